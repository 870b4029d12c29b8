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

What chance alone gives: if both runs' seeds were draws of one distribution (nothing
changed), a median of 3 seeds lands above the largest of 3 earlier seeds with probability
1/5, and below the smallest with 1/5 (``beyond_by_chance``), so the verdicts above count
about a fifth of the figures worse with no change at all. Each row also says whether every
seed now lies beyond every earlier seed ("separated": 1 in 20 on each side by chance with
3 and 3 seeds, ``separated_by_chance``), the stronger sign that a figure moved.

``--json`` writes the rows marked as the tool's, checked by the output rule before any file is
read and written atomically: it replaces only a file the tool wrote.
"""

import argparse
import json
import math
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402
from vdnif_addon.text import percent  # noqa: E402
from vdnif_addon.text import value as text_value  # noqa: E402

THEN = tuple(f"docs/results/deformation-{scene}.json"
             for scene in ("arm", "lattice", "spot", "bunny"))
NOW = ("docs/results/deformation-arm-lattice.json", "docs/results/deformation-spot-bunny.json")
METRICS = {"distance_mae": "distance MAE", "normal_error_deg": "normal error (deg)",
           "false_negative_rate": "holes", "false_positive_rate": "extras"}
REFERENCES = ("true", "embedded")
FORMAT = "vdnif-seed-spread-check"
"""The rows' format mark: the output rule lets ``--json`` replace only the tool's own file."""


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


def beyond_by_chance(seeds_before, seeds_now):
    """The probability that the median of ``seeds_now`` draws (an odd count) lies above the
    largest of ``seeds_before`` draws of the same continuous distribution (as likely as below
    the smallest): at least (n + 1) / 2 of the new draws above every earlier one, which is
    the top (n + 1) / 2 ranks of the pooled draws all being new."""
    if seeds_now % 2 == 0:
        raise VDNIFError(f"a median of {seeds_now} seeds is not one of them: use an odd count")
    top = (seeds_now + 1) // 2
    return math.comb(seeds_before + seeds_now - top, seeds_now - top) / math.comb(
        seeds_before + seeds_now, seeds_now)


def separated_by_chance(seeds_before, seeds_now):
    """The probability that every one of ``seeds_now`` draws lies above every one of
    ``seeds_before`` draws of the same continuous distribution (as likely as below)."""
    return 1 / math.comb(seeds_before + seeds_now, seeds_now)


def separated(now_seeds, low, high):
    """"worse" where every seed now lies above the earlier seeds' largest, "better" where
    every one lies below their smallest, else "overlapping"."""
    if min(now_seeds) > high:
        return "worse"
    return "better" if max(now_seeds) < low else "overlapping"


def compare(before, now):
    """Rows (run, reference, metric, now's median, before's median, before's min, max,
    now's min, max, verdict, separated) for every run with seeds in both: ``before`` and
    ``now`` map a run's name to its record (an experiment JSON's ``runs``)."""
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
                now_seeds = [seed["common"][f"vs_{reference}"].get(key)
                             for seed in record["seeds"]]
                if median is None or None in seeds or None in now_seeds:
                    continue
                old = earlier["common"][f"vs_{reference}"][key]
                rows.append({"run": run, "reference": reference, "metric": key,
                             "now": median, "before": old, "before_min": min(seeds),
                             "before_max": max(seeds), "seeds_before": len(seeds),
                             "seeds_now": len(record["seeds"]),
                             "now_min": min(now_seeds), "now_max": max(now_seeds),
                             "verdict": verdict(median, min(seeds), max(seeds)),
                             "separated": separated(now_seeds, min(seeds), max(seeds))})
    return rows


def chance_counts(rows):
    """Per side, the probability and the expected count of figures beyond the earlier seeds
    (median beyond their range; every seed beyond every one) if nothing had changed."""
    beyond = sum(beyond_by_chance(r["seeds_before"], r["seeds_now"]) for r in rows)
    apart = sum(separated_by_chance(r["seeds_before"], r["seeds_now"]) for r in rows)
    return {"what": "if both runs' seeds were draws of one distribution, per side",
            "beyond_probability": beyond / len(rows), "beyond_expected": beyond,
            "separated_probability": apart / len(rows), "separated_expected": apart}


def _number(key, value):
    return percent(value) if key.endswith("_rate") else text_value(value)


def table(rows):
    lines = ["| run | reference | metric | median now | median before | seeds before (min - "
             "max) | seeds now (min - max) | median | every seed |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        key = row["metric"]
        mark, apart = (f"**{word}**" if word == "worse" else word
                       for word in (row["verdict"], row["separated"]))
        lines.append(f"| {row['run']} | {row['reference']} | {METRICS[key]} | "
                     f"{_number(key, row['now'])} | {_number(key, row['before'])} | "
                     f"{_number(key, row['before_min'])} - {_number(key, row['before_max'])} "
                     f"| {_number(key, row['now_min'])} - {_number(key, row['now_max'])} "
                     f"| {mark} | {apart} |")
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
    if args.json:
        check_output_file(args.json, "--json", "json")      # the output rule, before the work
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
    separations = {name: sum(row["separated"] == name for row in rows)
                   for name in ("better", "overlapping", "worse")}
    chance = chance_counts(rows)
    print(f"\n{len(rows)} figures: " + ", ".join(f"{n} {name}" for name, n in counts.items())
          + f" (by chance alone about {chance['beyond_expected']:.1f} each side)")
    print("every seed beyond every earlier seed: " + ", ".join(
        f"{n} {name}" for name, n in separations.items())
          + f" (by chance alone about {chance['separated_expected']:.1f} each side)")
    if args.json:
        write_json_atomic(args.json, stamp({
            "format": FORMAT,
            "what": "medians now against the seed spread of the run committed at --before",
            "command": ["python", "tools/seed_spread_check.py", "--before", args.before,
                        "--then", *args.then, "--now", *args.now],
            "before": args.before, "counts": counts, "separated": separations,
            "chance": chance, "rows": rows}), "--json", indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="seed_spread_check: error: ")
