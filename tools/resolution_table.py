"""The resolution study: ``--resolution auto`` on a set of meshes, each trained at the resolution
it picks and evaluated on unseen test poses. Per case: the suggestion (every candidate's
embedding error and hit mismatch, the knee, the thin parts' floor, the chosen resolution
and whether it meets the target), then ``train`` at the chosen resolution by the recipe,
then ``evaluate`` on 8 test poses at 256x256 on the CPU: holes and extras against the true
reference, and whether both are within the clean rate.

    python tools/resolution_table.py run --case arm --case cup --out docs/results/resolution-auto
    python tools/resolution_table.py table docs/results/resolution-auto \\
        --json docs/results/resolution-auto.json

``run --suggest-only`` writes the suggestion alone (the row then says it was not trained).

``run`` writes ``CASE.json`` per case into --out (cases may run in several processes at
once), each checked by the output rule before the case starts and written atomically;
``table`` prints the Markdown table of every ``*.json`` in the folder and, with ``--json``,
writes them together as one list there (checked first, so an unmarked list of an earlier
run is refused: remove it to replace it). Cases: the demo scenes (arm, lattice, spot,
bunny), the skinned character of ``tools/skinned_character.py`` (its own armature and
actions) and the thin-walled cup and holed plate of ``tools/resolution_meshes.py``.
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402

FORMAT = "vdnif-resolution-case"
BATCH = [sys.executable, str(ROOT / "vdnif_addon" / "batch.py"), "--"]
EVALUATION = ["--poses", "8", "--width", "256", "--height", "256", "--device", "cpu"]
# case: (how its mesh file is written into a folder, or None; the scene options)
CASES = {
    "arm": (None, ["--scene", "arm"]),
    "lattice": (None, ["--scene", "lattice"]),
    "spot": (None, ["--scene", "spot"]),
    "bunny": (None, ["--scene", "bunny"]),
    "character": ("character.glb", ["--mesh", "{file}", "--pose-source", "frames"]),
    "cup": ("cup.obj", ["--mesh", "{file}"]),
    "plate": ("plate.obj", ["--mesh", "{file}", "--rig", "lattice"]),
}


def write_mesh(case, folder):
    """Writes the mesh file of ``case`` into ``folder``; its path (None for a demo scene)."""
    name = CASES[case][0]
    if name is None:
        return None
    path = pathlib.Path(folder) / name
    if case == "character":
        subprocess.run([sys.executable, str(ROOT / "tools" / "skinned_character.py"), "--out",
                        str(path)], check=True, stdout=subprocess.DEVNULL)
    else:
        import resolution_meshes

        getattr(resolution_meshes, case)(path)
    return path


def suggestion_of(options):
    """The Suggestion of the scene of ``options`` (``blender.resolution``), as plain data,
    and its seconds."""
    from vdnif_addon.blender.resolution import suggest_resolution
    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.options import load_posed_scene

    args = build_parser().parse_args(["train", *options])
    obj, spec = load_posed_scene(args)
    start = time.perf_counter()
    suggestion = suggest_resolution(obj, spec)
    floor = suggestion.floor
    return {"resolution": suggestion.resolution, "table": suggestion.table,
            "knee": suggestion.knee["resolution"], "target": suggestion.target,
            "met": suggestion.met, "none_met": suggestion.none_met,
            "thin_floor": floor.thin, "textured_floor": floor.textured,
            "thickness": floor.thickness, "object_size": floor.size,
            "describe": suggestion.describe(), "seconds": time.perf_counter() - start}


def run_case(case, out, train=True):
    """Suggests, trains and evaluates ``case`` (with ``train`` False, only suggests); writes
    ``out/CASE.json``."""
    from vdnif_addon.inference.metrics import CLEAN_RATE

    with tempfile.TemporaryDirectory(prefix=f"vdnif-{case}-") as folder:
        mesh = write_mesh(case, folder)
        options = [item.format(file=mesh) for item in CASES[case][1]]
        suggested = suggestion_of(options)
        print(f"{case}: {suggested['describe']}", flush=True)
        if not train:
            _write(out, {"case": case, "options": _named(options, case, mesh),
                         "suggestion": suggested, "training": None, "cpu": _cpu(),
                         "load_average": os.getloadavg()})
            return
        model, summary, report = (pathlib.Path(folder) / name for name in (
            "model.vdnif", "train.json", "evaluate.json"))
        start = time.perf_counter()
        subprocess.run([*BATCH, "train", *options, "--resolution",
                        str(suggested["resolution"]), "--out", str(model), "--json",
                        str(summary)], check=True, stdout=subprocess.DEVNULL)
        train_s = time.perf_counter() - start
        subprocess.run([*BATCH, "evaluate", "--model", str(model), *options, *EVALUATION,
                        "--json", str(report)], check=True, stdout=subprocess.DEVNULL)
        trained = json.loads(summary.read_text())
        evaluated = json.loads(report.read_text())
        from vdnif_addon.model.model_file import load_model

        thresholds = load_model(model)[1].thresholds
        figures = evaluated["vs_true"]
    holes, extras = figures["false_negative_rate"], figures["false_positive_rate"]
    row = {"case": case, "options": _named(options, case, mesh), "suggestion": suggested,
           "training": {"wall_s": train_s, "status": trained["train"]["status"],
                        "steps": trained["train"]["steps"], "segments": trained["segments"],
                        "occlusion_threshold": thresholds.occlusion,
                        "candidate_threshold": thresholds.candidate},
           "test": figures, "test_vs_embedded": evaluated.get("vs_embedded"),
           "clean": holes <= CLEAN_RATE and extras <= CLEAN_RATE,
           "cpu": _cpu(), "load_average": os.getloadavg()}
    _write(out, row)
    print(f"{case}: R {suggested['resolution']}, holes {100 * holes:.3g} %, extras "
          f"{100 * extras:.3g} %, clean {row['clean']}", flush=True)


def _named(options, case, mesh):
    """``options`` with the temporary mesh file named by its file name alone."""
    return [item.replace(str(mesh), CASES[case][0]) for item in options] if mesh else options


def _write(out, row):
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # each case trains in its own process, perhaps at another commit: its own record
    from vdnif_addon.safe_io import write_json_atomic

    row = stamp({"format": FORMAT, **row}, with_machine=True)
    write_json_atomic(out / f"{row['case']}.json", row, "--out", indent=1)


def _cpu():
    from vdnif_addon.kernels.runtime import cpu_description

    return cpu_description()[0]


def table(folder, json_path=None):
    """The Markdown table of the case files in ``folder``; with ``json_path``, writes them
    there together as one list."""
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise VDNIFError(f"run folder '{folder}' is not a folder")
    if json_path is not None:
        check_output_file(json_path, "--json", "json")
    rows = [json.loads(path.read_text()) for path in sorted(folder.glob("*.json"))]
    if not rows:
        raise VDNIFError(f"run folder '{folder}' holds no case files (CASE.json)")
    order = list(CASES)
    rows.sort(key=lambda row: order.index(row["case"]) if row["case"] in order else 99)
    if json_path is not None:
        write_json_atomic(json_path, rows, "--json", indent=1)
    lines = ["| mesh | chosen R (knee; thin-part floor) | its embedding error | finest (R 128) "
             "embedding error | target met | occlusion threshold | holes | extras | clean |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        s = row["suggestion"]
        chosen = next(r for r in s["table"] if r["resolution"] == s["resolution"])
        finest = s["table"][-1]
        lines.append(
            f"| {row['case']} | {s['resolution']} ({s['knee']}; {s['thin_floor'] or '-'}) | "
            f"{chosen['embedding_error']:.2g} | {finest['embedding_error']:.2g} | "
            f"{'yes' if s['met'] else 'no'} | " + (
                f"{_threshold(row['training'])} | "
                f"{100 * row['test']['false_negative_rate']:.3g} % | "
                f"{100 * row['test']['false_positive_rate']:.3g} % | "
                f"{'yes' if row['clean'] else 'no'} |" if row.get("training")
                else "- | not trained | not trained | - |"))
    return "\n".join(lines)


def _threshold(training):
    """The trained model's occlusion threshold as the table shows it ("-" where the run
    predates its record)."""
    value = training.get("occlusion_threshold")
    return "-" if value is None else f"{value:g}"


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="suggest, train and evaluate cases")
    run.add_argument("--case", action="append", choices=tuple(CASES), required=True)
    run.add_argument("--out", type=pathlib.Path, required=True, help="folder of CASE.json")
    run.add_argument("--suggest-only", action="store_true",
                     help="only the suggestion (no training, no evaluation)")
    show = commands.add_parser("table", help="the Markdown table of a run folder")
    show.add_argument("folder", type=pathlib.Path)
    show.add_argument("--json", type=pathlib.Path, metavar="OUT",
                      help="write the folder's rows here together as one list")
    args = parser.parse_args(argv)
    if args.command == "table":
        print(table(args.folder, args.json))
        return
    from vdnif_addon.safe_io import check_output_file
    from vdnif_addon.threads import use_threads

    for case in args.case:              # the output rule, before any case starts
        check_output_file(args.out / f"{case}.json", "--out", "json")
    use_threads(None)                   # as the batch commands do
    for case in args.case:
        run_case(case, args.out, train=not args.suggest_only)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="resolution_table: error: ")
