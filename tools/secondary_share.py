"""The share of training rays that start on the surface and leave it
(``Recipe.secondary_fraction``, ``dataset --secondary-fraction``), chosen on development poses
and reported on test poses:
each scene and share is one dataset at that share (the recipe otherwise), one training (seed
0, torch on one thread) and two evaluations with the secondary rays, on 8 development and 8
test poses at 256x256 against the true reference.

    python tools/secondary_share.py run --out out/secondary-share \\
        --run bunny:0 --run spot:0 --run bunny:0.1 --run spot:0.1 --run bunny:0.2
    python tools/secondary_share.py table out/secondary-share \\
        --json docs/results/secondary-rays.json

``run`` keeps each run's model and reports in OUT/SCENE-SHARE (``M.vdnif``, ``train.json``,
``development.json``, ``test.json``) and skips the parts a run already holds; ``table`` prints
the Markdown table and, with ``--json``, writes the runs together there, stamped with this
checkout's provenance and marked as the study's (checked before anything is read, so an
unmarked file is refused: remove it to replace it).
"""

import argparse
import json
import os
import pathlib
import shutil
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from resolution_table import BATCH  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.settings import RECIPE_RESOLUTION  # noqa: E402
from vdnif_addon.text import percent  # noqa: E402
from vdnif_addon.text import value as text_value  # noqa: E402

FORMAT = "vdnif-secondary-share"
"""The table's format mark: the output rule lets ``table --json`` replace only its own file."""
POSE_SETS = ("development", "test")
EVALUATION = ("--poses", "8", "--width", "256", "--height", "256", "--secondary",
              "--device", "cpu")


def commands(scene, share, folder):
    """The batch commands of one run (scene, share) into ``folder``: (dataset, train, and an
    evaluation per pose set), each an argument list after ``batch.py --``."""
    folder = pathlib.Path(folder)
    data, model = folder / "data", folder / "M.vdnif"
    # the recipe's fixed resolution, which the study's table was measured at
    return ([["dataset", "--scene", scene, "--secondary-fraction", str(share), "--resolution",
              RECIPE_RESOLUTION, "--out", str(data)],
             ["train", "--data", str(data), "--out", str(model), "--json",
              str(folder / "train.json")]]
            + [["evaluate", "--model", str(model), "--scene", scene, *EVALUATION,
                "--pose-set", pose_set, "--json", str(folder / f"{pose_set}.json")]
               for pose_set in POSE_SETS])


def parse_run(text):
    """'SCENE:SHARE' as (scene, share); anything else raises VDNIFError."""
    scene, _, share = text.partition(":")
    try:
        value = float(share)
    except ValueError:
        value = None
    if not scene or value is None or not 0.0 <= value < 1.0:
        raise VDNIFError(f"run '{text}' is not SCENE:SHARE with a share in [0, 1)")
    return scene, value


def run_folder(out, scene, share):
    return pathlib.Path(out) / f"{scene}-{share:.1f}"


def run(out, scene, share):
    """One run into OUT/SCENE-SHARE: the dataset and training unless its model is there, each
    evaluation unless its report is there. The dataset is removed once trained (it is
    gigabytes)."""
    folder = run_folder(out, scene, share)
    folder.mkdir(parents=True, exist_ok=True)
    dataset, train, *evaluations = commands(scene, share, folder)
    one_thread = dict(os.environ, OMP_NUM_THREADS="1")
    if not (folder / "M.vdnif").exists():
        subprocess.run([*BATCH, *dataset], check=True, stdout=subprocess.DEVNULL)
        subprocess.run([*BATCH, *train], check=True, stdout=subprocess.DEVNULL, env=one_thread)
        shutil.rmtree(folder / "data")
    for pose_set, evaluation in zip(POSE_SETS, evaluations):
        if not (folder / f"{pose_set}.json").exists():
            subprocess.run([*BATCH, *evaluation], check=True, stdout=subprocess.DEVNULL)


def collect(folder):
    """{"SCENE/SHARE": {scene, secondary_fraction, development, test}} of every run in
    ``folder`` holding both evaluations, scenes in name order and shares rising."""
    runs = {}
    for path in sorted(pathlib.Path(folder).iterdir()):
        scene, _, share = path.name.rpartition("-")
        reports = [path / f"{pose_set}.json" for pose_set in POSE_SETS]
        if not (path.is_dir() and scene and all(report.is_file() for report in reports)):
            continue
        runs[f"{scene}/{float(share)}"] = {
            "scene": scene, "secondary_fraction": float(share),
            **{pose_set: json.loads(report.read_text())
               for pose_set, report in zip(POSE_SETS, reports)}}
    if not runs:
        raise VDNIFError(f"no run with both evaluations in '{folder}'")
    return dict(sorted(runs.items(), key=lambda item: (item[1]["scene"],
                                                       item[1]["secondary_fraction"])))


def markdown(runs):
    """The Markdown table of ``runs`` against the true reference, each run's development poses
    (the choice's) and then its test poses (the report's)."""
    lines = ["| scene | share | poses | holes / extras | primary distance MAE | primary normal "
             "(deg) | AO MAE, own / true hits | false lit, own / true hits | false shadow, own "
             "/ true hits | shaded PSNR (dB) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for record in runs.values():
        for pose_set in POSE_SETS:
            m = record[pose_set]["vs_true"]
            lines.append(
                f"| {record['scene']} | {record['secondary_fraction']:g} | {pose_set} | "
                f"{percent(m['false_negative_rate'])} / {percent(m['false_positive_rate'])} | "
                f"{text_value(m['distance_mae'])} | {m['normal_error_deg']:.2f} | "
                f"{m['ao_mae']:.3g} / {m['ao_mae_true_hit']:.3g} | "
                f"{percent(m['shadow_false_lit_rate'])} / "
                f"{percent(m['shadow_false_lit_rate_true_hit'])} | "
                f"{percent(m['shadow_false_shadow_rate'])} / "
                f"{percent(m['shadow_false_shadow_rate_true_hit'])} | "
                f"{m['shaded_psnr']:.2f} |")
    return "\n".join(lines)


def table(folder, json_path=None):
    """The table of the runs in ``folder``; writes them together to ``json_path`` when
    given."""
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    if json_path is not None:
        check_output_file(json_path, "--json", "json")
    runs = collect(folder)
    if json_path is not None:
        record = {"format": FORMAT,
                  "commands": [" ".join(["python vdnif_addon/batch.py --", *command])
                               for command in commands("S", "F", "OUT")],
                  "note": "one training (seed 0) per scene and share, torch on 1 thread, "
                          "the recipe otherwise; the share is chosen on the development "
                          "poses and reported on the test poses",
                  "runs": runs}
        write_json_atomic(json_path, stamp(record), "--json", indent=1)
    return markdown(runs)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    runs = sub.add_parser("run", help="train and evaluate scenes at shares")
    runs.add_argument("--out", type=pathlib.Path, required=True, help="the runs' folder")
    runs.add_argument("--run", action="append", required=True,
                      metavar="SCENE:SHARE", help="a scene and its share (repeatable)")
    show = sub.add_parser("table", help="the table of a runs' folder")
    show.add_argument("folder", type=pathlib.Path)
    show.add_argument("--json", type=pathlib.Path, help="write the runs together here")
    args = parser.parse_args(argv)
    if args.command == "table":
        print(table(args.folder, args.json))
        return
    for scene, share in [parse_run(text) for text in args.run]:
        run(args.out, scene, share)
        print(f"{scene} at share {share:g}: done", flush=True)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="secondary_share: error: ")
