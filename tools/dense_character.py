"""The dense character: the skinned character of ``tools/skinned_character.py`` with a
Subdivision Surface modifier after its armature (``--subdivide-after-rig``), at several
levels, each trained through the batch commands as a user's .blend (its own armature and
actions, ``--pose-source frames``), evaluated on its test frames at 256x256 against the true
reference, and its pose cost timed beside Warp's and Embree's refit of the evaluated mesh
by the side-by-side study's own timing (``studies.side_by_side.compare_paths``: Blender's
evaluation of the mesh counted in every classical pose, the corners' in the neural one),
at 256x256 and 64x64, at 1 thread and at every core; and the corners' own cost per pose,
bound to the cage or to the subdivided surface against copies of the armature. The
crossover is interpolated on the levels as the side-by-side study does on Suzanne.

    python tools/dense_character.py train --levels 2 --out DIR     # one level a process
    python tools/dense_character.py time --levels 2 3 4 --out DIR --json PATH --markdown PATH

``train`` writes DIR/character-N.blend, .vdnif and .json (training and test figures);
``time`` reads them and writes the timings, the crossover and a Markdown summary. The
study's own files (each level's character-N.json, ``time``'s --json and --markdown) are
marked as its, checked by the output rule before any level is built, trained or timed (each
replaces only a file the study wrote) and written atomically.
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tools")]

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.output_rule import unmarked  # noqa: E402

LEVEL_FORMAT = "vdnif-dense-character-level"
"""A level's run file's format mark: the output rule lets ``train`` replace only its own."""
FORMAT = "vdnif-dense-character"
"""The timings' format mark: the output rule lets ``time --json`` replace only its own file."""
BATCH = [sys.executable, str(ROOT / "vdnif_addon" / "batch.py"), "--"]
OBJECT = "Character"
# The resolution --resolution auto chooses for the character (its limbs span two voxels
# there; at the default 32 the extras at their edges exceed the clean rate).
RESOLUTION = 48
EVALUATION = ["--poses", "8", "--width", "256", "--height", "256", "--device", "cpu"]
SIZES = ((256, 256), (64, 64))


def _files(out, level):
    stem = pathlib.Path(out) / f"character-{level}"
    return {kind: stem.with_suffix(suffix) for kind, suffix in (
        ("blend", ".blend"), ("model", ".vdnif"), ("row", ".json"),
        ("train", ".train.json"), ("evaluate", ".evaluate.json"))}


def train(level, out):
    """Writes the character at ``level``, trains and evaluates it; the row's figures."""
    from vdnif_addon.inference.metrics import CLEAN_RATE

    files = _files(out, level)
    files["blend"].parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, str(ROOT / "tools" / "skinned_character.py"),
                    "--subdivide-after-rig", str(level), "--out", str(files["blend"])],
                   check=True, stdout=subprocess.DEVNULL)
    scene = ["--blend", str(files["blend"]), "--object", OBJECT, "--pose-source", "frames"]
    start = time.perf_counter()
    subprocess.run([*BATCH, "train", *scene, "--resolution", str(RESOLUTION), "--out",
                    str(files["model"]), "--json", str(files["train"])],
                   check=True, stdout=subprocess.DEVNULL)
    train_s = time.perf_counter() - start
    subprocess.run([*BATCH, "evaluate", "--model", str(files["model"]), *scene, *EVALUATION,
                    "--json", str(files["evaluate"])], check=True, stdout=subprocess.DEVNULL)
    trained = json.loads(files["train"].read_text())
    evaluated = json.loads(files["evaluate"].read_text())
    figures = evaluated["vs_true"]
    row = {"level": level, "options": [*scene[2:], "--resolution", str(RESOLUTION)],
           "training": {"wall_s": train_s, "status": trained["train"]["status"],
                        "steps": trained["train"]["steps"],
                        "segments": trained["segments"]},
           "test": figures, "test_vs_embedded": evaluated.get("vs_embedded"),
           "clean": (figures["false_negative_rate"] <= CLEAN_RATE
                     and figures["false_positive_rate"] <= CLEAN_RATE)}
    _write(files["row"], row)
    print(f"level {level}: holes {100 * figures['false_negative_rate']:.3g} %, extras "
          f"{100 * figures['false_positive_rate']:.3g} %, clean {row['clean']}", flush=True)


def _write(path, row):
    from vdnif_addon.kernels.runtime import cpu_description
    from vdnif_addon.model.provenance import stamp
    from vdnif_addon.safe_io import write_json_atomic

    row = stamp({"format": LEVEL_FORMAT, **row, "cpu": cpu_description()[0],
                 "load_average": os.getloadavg()}, with_machine=True)
    write_json_atomic(path, row, "--out", indent=1)


def time_levels(levels, out, poses, repeats, threads):
    """(the side-by-side results of every level (``compare_paths``), scenes named
    character-N; the corners' cost per pose each way of following, ``pose_costs`` of
    ``tools/surface_corners_study.py``)."""
    import bpy
    from surface_corners_study import pose_costs

    from vdnif_addon.blender.steps import model_capture
    from vdnif_addon.model.model_file import load_model
    from vdnif_addon.pose_sets import PoseSpec
    from vdnif_addon.posed.render import load_scene_model
    from vdnif_addon.studies.side_by_side import compare_paths, thread_settings

    for level in levels:            # every level's files, before the first is timed
        for kind in ("blend", "model"):
            if not _files(out, level)[kind].is_file():
                raise VDNIFError(f"level {level} has no trained character in '{out}' (no "
                                 f"'{_files(out, level)[kind].name}'): run 'train' first")
    results, costs = [], []
    for level in levels:
        files = _files(out, level)
        bpy.ops.wm.open_mainfile(filepath=str(files["blend"]))
        obj = bpy.data.objects[OBJECT]
        loaded = load_model(files["model"])
        captured = model_capture(obj, loaded[1], PoseSpec(count=poses, source="frames"),
                                 evaluation=True)
        model = load_scene_model(files["model"], captured, "cpu", loaded)
        costs.append({"level": level, **pose_costs(obj, RESOLUTION, poses, cage_too=True)})
        for (width, height) in SIZES:
            for setting in thread_settings(threads):
                result = compare_paths(obj, captured, model, width, height, repeats,
                                       threads=setting)
                result["scene"] = f"character-{level}"
                results.append(result)
                print(f"level {level}, {width}x{height}, {setting} threads: "
                      + ", ".join(f"{name} {_total(result, name)}" for name in (
                          "neural", "warp", "embree_refit")), flush=True)
    return results, costs


def _total(result, name):
    from vdnif_addon.studies.side_by_side_report import pose_total

    total = pose_total(result, name)
    return "n/a" if total is None else f"{total:.1f} ms"


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    trains = commands.add_parser("train", help="write, train and evaluate levels")
    trains.add_argument("--levels", type=int, nargs="+", required=True)
    trains.add_argument("--out", type=pathlib.Path, required=True)
    times = commands.add_parser("time", help="time the trained levels side by side")
    times.add_argument("--levels", type=int, nargs="+", required=True)
    times.add_argument("--out", type=pathlib.Path, required=True)
    times.add_argument("--poses", type=int, default=4, help="test frames timed a repeat")
    times.add_argument("--repeats", type=int, default=3)
    times.add_argument("--threads", nargs="+", default=["1", "all"])
    times.add_argument("--json", type=pathlib.Path, required=True)
    times.add_argument("--markdown", type=pathlib.Path)
    args = parser.parse_args(argv)
    from vdnif_addon.safe_io import (
        MARKDOWN_MARK,
        check_output_file,
        write_json_atomic,
        write_text_atomic,
    )

    if args.command == "train":
        for level in args.levels:       # the output rule, before any level starts
            check_output_file(_files(args.out, level)["row"], "--out", "json")
        for level in args.levels:
            train(level, args.out)
        return
    check_output_file(args.json, "--json", "json")        # the output rule, before the timing
    if args.markdown is not None:
        check_output_file(args.markdown, "--markdown", "markdown")
    from vdnif_addon.kernels.runtime import cpu_description
    from vdnif_addon.model.provenance import stamp
    from vdnif_addon.studies.side_by_side_crossover import crossover, crossover_markdown

    load_before = os.getloadavg()
    results, costs = time_levels(args.levels, args.out, args.poses, args.repeats, args.threads)
    data = crossover(results, sweep="character-")
    rows = [json.loads(_files(args.out, level)["row"].read_text()) for level in args.levels]
    rows = [unmarked(row) for row in rows]
    for row in rows:                     # the evaluated mesh's, as the timing read it
        row["triangles"] = next(r["triangles"] for r in results
                                if r["scene"] == f"character-{row['level']}")
    command = " ".join(["python", "tools/dense_character.py", *argv])
    machine = (f"{cpu_description()[0]}, {os.cpu_count()} cores, load average before "
               f"{load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}")
    write_json_atomic(args.json, stamp({
        "format": FORMAT, "command": command, "machine": machine, "levels": rows,
        "crossover": data, "corner_costs": costs, "results": results}, with_machine=True),
        "--json", indent=1)
    if args.markdown is not None:
        lines = [MARKDOWN_MARK, "| level | triangles | training s | holes | extras | clean |",
                 "| --- | --- | --- | --- | --- | --- |"]
        for row in rows:
            lines.append(f"| {row['level']} | {row['triangles']:,} | "
                         f"{row['training']['wall_s']:.0f} | "
                         f"{100 * row['test']['false_negative_rate']:.3g} % | "
                         f"{100 * row['test']['false_positive_rate']:.3g} % | "
                         f"{'yes' if row['clean'] else 'no'} |")
        lines += ["", *crossover_markdown(data, results, command, machine,
                                          sweep="the character's levels")]
        write_text_atomic(args.markdown, "\n".join(lines) + "\n", "--markdown", "markdown")


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="dense_character: error: ")
