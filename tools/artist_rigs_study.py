"""Rigs as artists build them, trained: each small rig of ``tests/support/artist_rigs.py``
(a Subdivision after the armature, a bone-driven corrective key, a Corrective Smooth, a
lattice with an animated shape key, a Mesh Deform cage, a Hook, a node tree moving points
over the frames) and its armature-only (lattice-only) twin is saved as a .blend and goes
through the batch commands as a user's file would: ``train`` with the defaults, then
``evaluate`` on 8 test poses or frames at 256x256 on the CPU against the true reference
(Blender's evaluated mesh) and the embedded one; beside them the voxel embedding's own error
(embedded against true) on the same poses, and how the corners followed. The
topology-changing stack is given to ``train`` too, which must refuse it in one line.

    python tools/artist_rigs_study.py run --case hook --case twin-frames --out DIR
    python tools/artist_rigs_study.py table DIR --json docs/results/artist-rigs.json

(``embed DIR`` computes the embedding's error of every trained case in DIR again.)

``run`` writes ``CASE.json`` per case into --out (cases may run in several processes at
once), each checked by the output rule before any case starts and written atomically, as
``embed`` rewrites them; ``table`` prints the Markdown table of every ``*.json`` there and,
with ``--json``, writes them together as one list there (checked first, so an unmarked list
of an earlier run is refused: remove it to replace it).
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
sys.path[:0] = [str(ROOT), str(ROOT / "tools"), str(ROOT / "tests" / "support")]

from vdnif_addon.errors import VDNIFError  # noqa: E402

FORMAT = "vdnif-artist-rig-case"
"""A case file's format mark: the output rule lets ``run`` and ``embed`` replace only the
study's own files."""
BATCH = [sys.executable, str(ROOT / "vdnif_addon" / "batch.py"), "--"]
EVALUATION = ["--poses", "8", "--width", "256", "--height", "256", "--device", "cpu"]
OBJECT = "Box"
# case: (rig of artist_rigs, full rig or its twin); the twins of the rigs that share one
# (the armature box posed at random, the lattice box, the armature box over the frames).
CASES = {
    "subdivision": ("subdivision", True),
    "driven-key": ("driven_key", True),
    "corrective-smooth": ("corrective_smooth", True),
    "twin-random": ("subdivision", False),
    "lattice-key": ("lattice_key", True),
    "twin-lattice": ("lattice_key", False),
    "mesh-deform": ("mesh_deform", True),
    "hook": ("hook", True),
    "nodes-wobble": ("nodes_wobble", True),
    "twin-frames": ("hook", False),
    "topology": (None, True),
}
LABELS = {
    "subdivision": "armature + Subdivision after it",
    "driven-key": "armature + bone-driven corrective key",
    "corrective-smooth": "armature + Corrective Smooth",
    "twin-random": "armature only (random poses)",
    "lattice-key": "lattice + animated shape key",
    "twin-lattice": "lattice only",
    "mesh-deform": "Mesh Deform cage on two bones (frames)",
    "hook": "armature + Hook to an animated empty (frames)",
    "nodes-wobble": "armature + node tree Set Position by frame (frames)",
    "twin-frames": "armature only (frames)",
    "topology": "armature + node tree deleting faces above a height",
}
TWIN = {"subdivision": "twin-random", "driven-key": "twin-random",
        "corrective-smooth": "twin-random", "lattice-key": "twin-lattice",
        "mesh-deform": "twin-frames", "hook": "twin-frames", "nodes-wobble": "twin-frames"}
EMBEDDING_FIGURES = ("distance_mae", "distance_mae_voxels", "hit_iou", "false_negative_rate",
                     "false_positive_rate", "normal_error_deg")


def _pose_options(keywords):
    """The batch commands' pose options for ``artist_rigs.build``'s PoseSpec keywords."""
    if keywords.get("source") == "frames":
        return ["--pose-source", "frames"]
    return ["--max-angle", str(keywords["max_angle_deg"])] if "max_angle_deg" in keywords \
        else []


def _build(case):
    """Builds ``case`` in an empty scene: (its object, PoseSpec keywords)."""
    import artist_rigs
    import bpy

    rig, full = CASES[case]
    bpy.ops.wm.read_homefile(use_empty=True)
    if rig is None:
        obj, keywords = artist_rigs.topology_changing(), {"max_angle_deg": 50}
    else:
        obj, keywords = artist_rigs.build(rig, full)
    bpy.context.view_layer.objects.active = obj
    return obj, keywords


def _save(case, folder):
    """Builds ``case`` and saves it as ``folder/CASE.blend``; (path, the object and its
    PoseSpec keywords, which stay in this session for the embedding's error)."""
    import bpy

    obj, keywords = _build(case)
    path = pathlib.Path(folder) / f"{case}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path, obj, keywords


def embed(out):
    """Adds to each trained case's row in ``out`` the voxel embedding's own error, its
    corners following as its model's did (the output rule: the study's own files only,
    every one checked before the first is measured)."""
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    paths = sorted(pathlib.Path(out).glob("*.json"))
    for path in paths:
        check_output_file(path, "case file", "json")
    for path in paths:
        row = json.loads(path.read_text())
        if "training" not in row:
            continue
        obj, keywords = _build(row["case"])
        row["embedding"] = _embedding(obj, keywords, row["training"]["corners_follow"])
        write_json_atomic(path, row, "case file", indent=1)
        print(f"{row['case']}: embedding {row['embedding']['distance_mae_voxels']:.3g} "
              f"voxel ({row['embedding']['corners_follow']})", flush=True)


def _embedding(obj, keywords, follow):
    """The voxel embedding's error (embedded against true reference) of ``obj`` on the 8
    test poses the evaluation uses, 256x256, at the recipe's resolution, the corners
    following as ``follow`` says (the trained model's way)."""
    from vdnif_addon.blender.capture_scene import capture
    from vdnif_addon.blender.poses import evaluation_spec
    from vdnif_addon.declarations import RESOLUTION
    from vdnif_addon.pose_sets import PoseSpec
    from vdnif_addon.posed.generate import reference_run

    resolution = RESOLUTION.default             # the box has no texture
    spec = evaluation_spec(PoseSpec(count=8, **keywords))
    captured = capture(obj, resolution, spec, deform_corners=False, follow=follow)
    error = reference_run(obj, captured, 256, 256)["embedded_vs_true"]
    return {"resolution": resolution, "corners_follow": captured.corners_follow,
            **{key: error.get(key) for key in EMBEDDING_FIGURES}}


def run_case(case, out):
    """Trains and evaluates ``case`` (or has ``train`` refuse it); writes ``out/CASE.json``."""
    row = {"case": case, "rig": LABELS[case], "twin": TWIN.get(case)}
    with tempfile.TemporaryDirectory(prefix=f"vdnif-{case}-") as folder:
        blend, obj, keywords = _save(case, folder)
        scene = ["--blend", str(blend), "--object", OBJECT, *_pose_options(keywords)]
        row["options"] = [item.replace(str(blend), blend.name) for item in scene]
        model, summary, report = (pathlib.Path(folder) / name for name in (
            "model.vdnif", "train.json", "evaluate.json"))
        start = time.perf_counter()
        # the recipe's fixed resolution, which the study's table was measured at
        trained = subprocess.run([*BATCH, "train", *scene, "--resolution", "recipe", "--out",
                                  str(model), "--json", str(summary)], stdout=subprocess.DEVNULL,
                                 stderr=subprocess.PIPE, text=True)
        train_s = time.perf_counter() - start
        if CASES[case][0] is None:
            lines = [line for line in trained.stderr.splitlines() if line.strip()]
            # the progress lines before it are stderr's too; the error is the last line
            row["refusal"] = {"exit_code": trained.returncode,
                              "error": lines[-1] if lines else None,
                              "error_lines": sum("error" in line for line in lines)}
            _write(out, row)
            print(f"{case}: exit {trained.returncode}: {row['refusal']['error']}", flush=True)
            return
        if trained.returncode:
            raise SystemExit(f"{case}: train failed: {trained.stderr.strip()}")
        subprocess.run([*BATCH, "evaluate", "--model", str(model), *scene, *EVALUATION,
                        "--json", str(report)], check=True, stdout=subprocess.DEVNULL)
        training = json.loads(summary.read_text())
        evaluated = json.loads(report.read_text())
        from vdnif_addon.model.model_file import load_model

        metadata = load_model(model)[1]
    from vdnif_addon.inference.metrics import CLEAN_RATE

    figures = evaluated["vs_true"]
    row.update(
        training={"wall_s": train_s, "status": training["train"]["status"],
                  "steps": training["train"]["steps"], "segments": training["segments"],
                  "variant": training["variant"], "resolution": metadata.grid.resolution,
                  "corners_follow": metadata.corners_follow,
                  "occlusion_threshold": metadata.thresholds.occlusion},
        test=figures, test_vs_embedded=evaluated.get("vs_embedded"),
        clean=(figures["false_negative_rate"] <= CLEAN_RATE
               and figures["false_positive_rate"] <= CLEAN_RATE))
    row["embedding"] = _embedding(obj, keywords, row["training"]["corners_follow"])
    _write(out, row)
    print(f"{case}: holes {100 * figures['false_negative_rate']:.3g} %, extras "
          f"{100 * figures['false_positive_rate']:.3g} %, clean {row['clean']}", flush=True)


def _write(out, row):
    from vdnif_addon.kernels.runtime import cpu_description
    from vdnif_addon.model.provenance import stamp
    from vdnif_addon.safe_io import write_json_atomic

    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    row = stamp({"format": FORMAT, **row, "cpu": cpu_description()[0],
                 "load_average": os.getloadavg()}, with_machine=True)
    write_json_atomic(out / f"{row['case']}.json", row, "--out", indent=1)


def _percent(value):
    return f"{100 * value:.3g} %"


def _allowed(twin_rate):
    """The most a rig's holes or extras may be: the clean rate, or within 0.1 point of its
    twin's where the twin is not clean either."""
    from vdnif_addon.inference.metrics import CLEAN_RATE

    return CLEAN_RATE if twin_rate <= CLEAN_RATE else twin_rate + 0.001


def table(folder, json_path=None):
    """The Markdown table of the case files in ``folder``; with ``json_path``, writes them
    there together as one list, in the study's order."""
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise VDNIFError(f"run folder '{folder}' is not a folder")
    if json_path is not None:
        check_output_file(json_path, "--json", "json")
    rows = {row["case"]: row for row in (json.loads(path.read_text())
                                          for path in sorted(folder.glob("*.json")))}
    ordered = [rows[case] for case in CASES if case in rows]
    if not ordered:
        raise VDNIFError(f"run folder '{folder}' holds no case files (CASE.json)")
    if json_path is not None:
        write_json_atomic(json_path, ordered, "--json", indent=1)
    lines = ["| rig | corners follow | holes | extras | clean | clean, or within 0.1 point "
             "of an unclean twin | embedding error, voxels (hit IoU) | training s | twin |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in ordered:
        if "refusal" in row:
            refusal = row["refusal"]
            lines.append(f"| {row['rig']} | refused (exit {refusal['exit_code']}): "
                         f"`{refusal['error']}` | - | - | - | - | - | - | - |")
            continue
        test, twin = row["test"], rows.get(row["twin"])
        within = "-"
        if twin is not None and "test" in twin:
            within = "yes" if all(test[key] <= _allowed(twin["test"][key])
                                  for key in ("false_negative_rate",
                                              "false_positive_rate")) else "no"
        embedding = row["embedding"]
        lines.append(
            f"| {row['rig']} | {row['training']['corners_follow']} | "
            f"{_percent(test['false_negative_rate'])} | "
            f"{_percent(test['false_positive_rate'])} | {'yes' if row['clean'] else 'no'} | "
            f"{within} | {embedding['distance_mae_voxels']:.3g} "
            f"({embedding['hit_iou']:.4f}) | {row['training']['wall_s']:.0f} | "
            f"{LABELS[row['twin']] if row['twin'] else '-'} |")
    return "\n".join(lines)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="train and evaluate cases")
    run.add_argument("--case", action="append", choices=list(CASES), required=True)
    run.add_argument("--out", required=True, type=pathlib.Path)
    show = commands.add_parser("table", help="the table of a folder of cases")
    show.add_argument("folder", type=pathlib.Path)
    show.add_argument("--json", type=pathlib.Path, metavar="OUT",
                      help="write the folder's rows here together as one list")
    again = commands.add_parser("embed", help="the embedding's error of each trained case")
    again.add_argument("folder", type=pathlib.Path)
    args = parser.parse_args(argv)
    if args.command == "table":
        print(table(args.folder, args.json))
        return
    if args.command == "embed":
        embed(args.folder)
        return
    from vdnif_addon.safe_io import check_output_file

    for case in args.case:              # the output rule, before any case starts
        check_output_file(args.out / f"{case}.json", "--out", "json")
    for case in args.case:
        run_case(case, args.out)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="artist_rigs_study: error: ")
