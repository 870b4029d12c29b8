"""The development-mesh study: each mesh of ``tools/dev_meshes.py`` trained with the defaults
as a user runs them (``train --mesh M --rig R --seed S``), then evaluated on 8 test poses at
256x256 on the CPU (``evaluate``, test pose set, pose seed 0 for every training seed):
holes (false negative rate) and extras (false positive rate) against the true reference,
clean when both are at most the clean rate (0.5 %).

    python tools/dev_mesh_study.py run --mesh text --seed 0 --out out/dev-meshes
    python tools/dev_mesh_study.py table out/dev-meshes --json docs/results/dev-meshes.json

``run`` writes ``MESH-seedS.json`` per training into --out (marked as the study's run file,
with the CPU, its cores, torch's
threads, the load average before and after, and the wall time of the training and of the
evaluation); ``--images DIR`` keeps evaluate's figures and error images in DIR/MESH-seedS,
``--keep DIR`` the mesh and the model as DIR/MESH.obj and DIR/MESH-seedS.vdnif (for the
shaded pass's study, ``tools/terminator_band.py``).
``table`` prints the Markdown table of every ``*.json`` in the folder and, with ``--json``
only, writes them together as one JSON file there. ``shaded`` evaluates kept models' shaded
pass on the same test poses (``tools/terminator_band.py``: PSNR, the visible-step share, the
shadow rates inside and outside the terminator band) and writes them together:

    python tools/dev_mesh_study.py shaded --keep out/kept --mesh blob --seed 1 \\
        --json docs/results/shaded-dev-meshes.json

Every file is written atomically under the output rule, checked before the work starts (the
--images folder as evaluate checks it, and evaluate's report copied into it): a run file
replaces only a run file of the study, and ``table`` and ``shaded`` write lists, which carry
no mark, so they replace nothing outside a folder VDNIF marked as its own (remove the old
file first, or write elsewhere).
"""

import argparse
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from resolution_table import BATCH, EVALUATION, _cpu  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.inference.metrics import CLEAN_RATE  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.output_rule import unmarked  # noqa: E402

MESHES_TOOL = ROOT / "tools" / "dev_meshes.py"
BAND_TOOL = ROOT / "tools" / "terminator_band.py"
FORMAT = "vdnif-dev-mesh-run"
"""A run file's format mark: the output rule lets ``run`` replace only its own files."""


def mesh_table():
    """``dev_meshes.MESHES`` (mesh: (rig, what it stresses)) without importing bpy here."""
    import ast

    tree = ast.parse(MESHES_TOOL.read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", None) == "MESHES":
            return ast.literal_eval(node.value)
    raise VDNIFError(f"no MESHES table in '{MESHES_TOOL}'")


def run_mesh(mesh, seed, out, images=None, keep=None, resolution=None):
    """Builds, trains and evaluates ``mesh`` at training seed ``seed`` (and ``--resolution
    resolution`` where given, else the default); writes ``out/MESH-seedS.json``."""
    from vdnif_addon.safe_io import check_output_file, check_output_folder, write_json_atomic
    from vdnif_addon.threads import default_threads, machine_cores

    rig = mesh_table()[mesh][0]
    kept = (pathlib.Path(keep) / f"{mesh}-seed{seed}.vdnif") if keep else None
    if kept is not None and kept.exists():
        raise VDNIFError(f"'{kept}' exists; the study does not replace a model")
    run_file = pathlib.Path(out) / f"{mesh}-seed{seed}.json"
    check_output_file(run_file, "the run file", "json")       # before an hour of training
    figures_folder = pathlib.Path(images) / f"{mesh}-seed{seed}" if images else None
    if figures_folder is not None:                  # evaluate's --out, checked as it will be
        check_output_folder(figures_folder, "--images folder")
    with tempfile.TemporaryDirectory(prefix=f"vdnif-{mesh}-") as folder:
        folder = pathlib.Path(folder)
        subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(folder), "--mesh",
                        mesh], check=True, stdout=subprocess.DEVNULL)
        path = folder / f"{mesh}.obj"
        kept_mesh = kept.parent / path.name if kept is not None else None
        if kept_mesh is not None and kept_mesh.exists() and \
                kept_mesh.read_bytes() != path.read_bytes():
            # another seed's run keeps the same mesh; any other file of that name is not ours
            raise VDNIFError(f"'{kept_mesh}' exists and is not the mesh '{mesh}' the study "
                             "builds; the study does not replace it")
        options = ["--mesh", str(path), "--rig", rig]
        chosen = [] if resolution is None else ["--resolution", str(resolution)]
        model, summary, report = (folder / name for name in (
            "model.vdnif", "train.json", "evaluate.json"))
        commit, load_before = _commit(), os.getloadavg()
        start = time.perf_counter()
        subprocess.run([*BATCH, "train", *options, *chosen, "--seed", str(seed), "--out",
                        str(model), "--json", str(summary)], check=True,
                       stdout=subprocess.DEVNULL)
        train_s = time.perf_counter() - start
        figures_out = ["--out", str(figures_folder)] if images else []
        start = time.perf_counter()
        subprocess.run([*BATCH, "evaluate", "--model", str(model), *options, *EVALUATION,
                        "--json", str(report), *figures_out], check=True,
                       stdout=subprocess.DEVNULL)
        evaluate_s = time.perf_counter() - start
        trained = json.loads(summary.read_text())
        evaluated = json.loads(report.read_text())
        if images:
            write_json_atomic(figures_folder / "evaluate.json", evaluated, "--images")
        figures = evaluated["vs_true"]
        if kept is not None:
            kept.parent.mkdir(parents=True, exist_ok=True)
            if not kept_mesh.exists():
                shutil.copyfile(path, kept_mesh)
            shutil.copyfile(model, kept)
    holes, extras = figures["false_negative_rate"], figures["false_positive_rate"]
    row = {"format": FORMAT, "mesh": mesh, "rig": rig, "seed": seed,
           "command": ["train", "--mesh", f"{mesh}.obj", "--rig", rig, *chosen, "--seed",
                       str(seed)],
           "resolution": evaluated.get("resolution"),
           "resolution_suggestion": trained.get("resolution_suggestion"),
           "evaluation": [*EVALUATION, "--pose-set", "test", "--seed", "0"],
           "training": {"wall_s": train_s, "status": trained["train"]["status"],
                        "steps": trained["train"]["steps"], "segments": trained["segments"]},
           "evaluate_wall_s": evaluate_s, "test": figures, "clean": is_clean(holes, extras),
           # The calibrated thresholds the figures were rendered at: a later calibration rule
           # can be judged against them without training again.
           "thresholds": evaluated.get("thresholds"),
           # The model against the embedded reference too (the rest surface carried through
           # the voxel grid, what the network learns): tells the network's error from the grid's.
           "test_embedded": evaluated.get("vs_embedded"),
           "commit": commit, "cpu": _cpu(), "cores": machine_cores(),
           "torch_threads": default_threads(), "load_average_before": load_before,
           "load_average_after": os.getloadavg()}
    write_json_atomic(run_file, stamp(row, with_machine=True), "the run file", indent=1)
    print(f"{mesh} seed {seed}: holes {100 * holes:.3g} %, extras {100 * extras:.3g} %, "
          f"clean {row['clean']}, training {train_s:.0f} s", flush=True)


def shaded(keep, meshes, seed, json_path):
    """The shaded pass of each kept model ``keep/MESH-seedS.vdnif`` on the test poses of
    the study's evaluation (``terminator_band.py --secondary``), written together to
    ``json_path``; returns the rows."""
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    check_output_file(json_path, "--json", "json")          # before the renders
    keep, rows = pathlib.Path(keep), []
    for mesh in meshes:
        model, obj = keep / f"{mesh}-seed{seed}.vdnif", keep / f"{mesh}.obj"
        if not (model.is_file() and obj.is_file()):
            raise VDNIFError(f"no kept model and mesh of '{mesh}' seed {seed} in '{keep}' "
                             "(run --keep first)")
        with tempfile.TemporaryDirectory(prefix=f"vdnif-{mesh}-shaded-") as folder:
            band = pathlib.Path(folder) / "band.json"
            subprocess.run([sys.executable, str(BAND_TOOL), "--model", str(model), "--mesh",
                            str(obj), "--rig", mesh_table()[mesh][0], *EVALUATION,
                            "--secondary", "--pose-set", "test", "--seed", "0", "--json",
                            str(band)], check=True, stdout=subprocess.DEVNULL)
            figures = unmarked(json.loads(band.read_text()))    # not the band tool's file
            rows.append({"mesh": mesh, "seed": seed, **figures})
    write_json_atomic(json_path, rows, "--json", indent=1)
    return rows


def is_clean(holes, extras):
    """The clean rule: holes and extras each at most CLEAN_RATE."""
    return holes <= CLEAN_RATE and extras <= CLEAN_RATE


def _commit():
    done = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                          text=True)
    return done.stdout.strip() or None


def table(folder, json_path=None):
    """The Markdown table of the run files in ``folder``; writes them together to
    ``json_path`` when given, without the run files' format mark."""
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    if json_path is not None:
        check_output_file(json_path, "--json", "json")
    rows = [json.loads(path.read_text()) for path in sorted(pathlib.Path(folder).glob("*.json"))]
    if not rows:
        raise VDNIFError(f"no run files (*.json) in '{folder}'")
    rows = [unmarked(row) for row in rows]
    order = list(mesh_table())
    rows.sort(key=lambda row: (order.index(row["mesh"]) if row["mesh"] in order else 99,
                               row["seed"]))
    if json_path is not None:
        write_json_atomic(json_path, rows, "--json", indent=1)
    lines = ["| mesh | rig | seed | resolution | holes | extras | clean | against the embedded "
             "reference: holes / extras | training wall (s) | steps | load average (1 min) "
             "before / after |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for row in rows:
        holes = row["test"]["false_negative_rate"]
        extras = row["test"]["false_positive_rate"]
        embedded = row.get("test_embedded")
        lines.append(
            f"| {row['mesh']} | {row['rig']} | {row['seed']} | "
            f"{row.get('resolution') or 'not recorded'} | {100 * holes:.3g} % | "
            f"{100 * extras:.3g} % | {'yes' if is_clean(holes, extras) else 'no'} | " + (
                f"{100 * embedded['false_negative_rate']:.3g} % / "
                f"{100 * embedded['false_positive_rate']:.3g} % | " if embedded
                else "not recorded | ") +
            f"{row['training']['wall_s']:.0f} | {row['training']['steps']:,} | "
            f"{row['load_average_before'][0]:.1f} / {row['load_average_after'][0]:.1f} |")
    return "\n".join(lines)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="build, train and evaluate meshes")
    run.add_argument("--mesh", action="append", choices=tuple(mesh_table()), required=True)
    run.add_argument("--seed", type=int, action="append",
                     help="training seed (repeatable; default 0)")
    run.add_argument("--out", type=pathlib.Path, required=True, help="folder of MESH-seedS.json")
    run.add_argument("--images", type=pathlib.Path, help="keep evaluate's images here")
    run.add_argument("--keep", type=pathlib.Path, help="keep the meshes and models here")
    run.add_argument("--resolution", help="train's --resolution (default: train's default)")
    show = commands.add_parser("table", help="the Markdown table of a run folder")
    show.add_argument("folder", type=pathlib.Path)
    show.add_argument("--json", type=pathlib.Path,
                      help="write the rows together here (nothing is written without it)")
    band = commands.add_parser("shaded", help="the shaded pass of kept models")
    band.add_argument("--keep", type=pathlib.Path, required=True,
                      help="the folder of run --keep")
    band.add_argument("--mesh", action="append", choices=tuple(mesh_table()), required=True)
    band.add_argument("--seed", type=int, default=0, help="training seed of the kept models")
    band.add_argument("--json", type=pathlib.Path, required=True,
                      help="write the rows together here")
    args = parser.parse_args(argv)
    if args.command == "shaded":
        for row in shaded(args.keep, args.mesh, args.seed, args.json):
            m = row["report"]["vs_true"]
            print(f"{row['mesh']}: shaded PSNR {m['shaded_psnr']:.3g} dB, visible steps "
                  f"{100 * m['shaded_visible_rate']:.3g} %")
        return
    if args.command == "table":
        print(table(args.folder, args.json))
        return
    for mesh in args.mesh:
        for seed in args.seed or [0]:
            run_mesh(mesh, seed, args.out, args.images, args.keep, args.resolution)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="dev_mesh_study: error: ")
