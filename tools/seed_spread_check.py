"""Whether an experiment's medians stayed within the seed spread of an earlier run of it: for
every run (scene and model) of the experiment JSON files ``--now`` in the working tree, the
median over seeds (its table's figure) against the smallest and largest seed of the same
run in the files ``--then`` as committed at ``--before``, for the spread table's four
headline metrics (distance MAE, normal error, holes, extras) against the true and the
embedded reference. Each figure is "better" (below the earlier seeds' smallest), "within"
their range, or "worse" (above the largest): every one of these metrics is an error, lower
is better. By default, Figure 3: its four per-scene files then, its two files now.

    python tools/seed_spread_check.py --before 5ae3d47 --json out/figure3-spread.json
    python tools/seed_spread_check.py --before 5ae3d47 \
        --then docs/results/ablation-arm-1-seed.json --now docs/results/ablation-arm-1-seed.json

Medians and seeds are each run's own: its common pixel set (where all its models and seeds
and the reference hit) is not the other run's.
"""

import argparse
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.text import percent  # noqa: E402
from vdnif_addon.text import value as text_value  # noqa: E402

THEN = tuple(f"docs/results/deformation-{scene}.json"
             for scene in ("arm", "lattice", "spot", "bunny"))
NOW = ("docs/results/deformation-arm-lattice.json", "docs/results/deformation-spot-bunny.json")
METRICS = {"distance_mae": "distance MAE", "normal_error_deg": "normal error (deg)",
           "false_negative_rate": "holes", "false_positive_rate": "extras"}
REFERENCES = ("true", "embedded")


def committed(path, commit):
    """The JSON of ``path`` (relative to the repository) as committed at ``commit``."""
    done = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{path}"],
                          capture_output=True, text=True)
    if done.returncode:
        raise VDNIFError(f"'{path}' at {commit}: {done.stderr.strip() or 'not found'}")
    return json.loads(done.stdout)


def verdict(value, low, high):
    if value < low:
        return "better"
    return "within" if value <= high else "worse"


def compare(before, now):
    """Rows (run, reference, metric, now's median, before's median, before's min, max,
    verdict) for every run with seeds in both: ``before`` and ``now`` map a run's name to
    its record (an experiment JSON's ``runs``)."""
    rows = []
    for run, record in now.items():
        earlier = before.get(run)
        if not (earlier and "seeds" in record and "seeds" in earlier):
            continue
        for reference in REFERENCES:
            for key in METRICS:
                seeds = [seed["common"][f"vs_{reference}"].get(key)
                         for seed in earlier["seeds"]]
                median = record["common"][f"vs_{reference}"].get(key)
                if median is None or None in seeds:
                    continue
                old = earlier["common"][f"vs_{reference}"][key]
                rows.append({"run": run, "reference": reference, "metric": key,
                             "now": median, "before": old, "before_min": min(seeds),
                             "before_max": max(seeds), "seeds_before": len(seeds),
                             "seeds_now": len(record["seeds"]),
                             "verdict": verdict(median, min(seeds), max(seeds))})
    return rows


def _number(key, value):
    return percent(value) if key.endswith("_rate") else text_value(value)


def table(rows):
    lines = ["| run | reference | metric | median now | median before | seeds before (min - "
             "max) | now |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        key = row["metric"]
        mark = f"**{row['verdict']}**" if row["verdict"] == "worse" else row["verdict"]
        lines.append(f"| {row['run']} | {row['reference']} | {METRICS[key]} | "
                     f"{_number(key, row['now'])} | {_number(key, row['before'])} | "
                     f"{_number(key, row['before_min'])} - {_number(key, row['before_max'])} "
                     f"| {mark} |")
    return "\n".join(lines)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="the commit of the earlier run")
    parser.add_argument("--then", nargs="+", default=THEN,
                        help="its experiment JSON files, relative to the repository")
    parser.add_argument("--now", nargs="+", default=NOW,
                        help="today's experiment JSON files, relative to the repository")
    parser.add_argument("--json", type=pathlib.Path, help="write the rows here")
    args = parser.parse_args(argv)
    before, now = {}, {}
    for path in args.now:
        if not (ROOT / path).is_file():
            raise VDNIFError(f"'{path}': no such file in the working tree")
        now.update(json.loads((ROOT / path).read_text())["runs"])
    for path in args.then:
        before.update(committed(path, args.before)["runs"])
    rows = compare(before, now)
    if not rows:
        raise VDNIFError("no run with seeds in both the earlier and the current files")
    print(table(rows))
    counts = {name: sum(row["verdict"] == name for row in rows)
              for name in ("better", "within", "worse")}
    print(f"\n{len(rows)} figures: " + ", ".join(f"{n} {name}" for name, n in counts.items()))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(stamp({
            "what": "medians now against the seed spread of the run committed at --before",
            "command": ["python", "tools/seed_spread_check.py", "--before", args.before,
                        "--then", *args.then, "--now", *args.now],
            "before": args.before, "counts": counts, "rows": rows}), indent=1))


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="seed_spread_check: error: ")
