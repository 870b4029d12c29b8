"""How long until a model is clean: trains the proposed variant by the recipe (or with
TrainConfig / NetworkConfig overrides) on one dataset folder, prints when the held-out
occlusion accuracy leaves the share of misses (the all-miss answer), the training's wall
seconds and steps, and then evaluates the model on the development poses and the test poses
(``evaluate --pose-set``; test is its default) at 256x256 against the true reference:
holes (false-negative rate), extras (false-positive rate), distance and normal. With
``--repeats N`` it trains N times and reports every run's wall seconds and their median; the
runs draw the same batches, so they give the same model, and the last one is evaluated.
``--json`` (marked as the tool's, written atomically) and ``--model`` are checked by the output
rule before the training: each replaces only a file of its kind that VDNIF wrote.

    python vdnif_addon/batch.py -- dataset --scene bunny --out out/bunny-data
    OMP_NUM_THREADS=1 python tools/time_to_clean.py --data out/bunny-data --scene bunny \\
        --json out/bunny-clean.json [--repeats 3] [--set lr_mlp=0.01 --set steps=3000] \\
        [--model out/bunny.vdnif]
"""

import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.inference.metrics import CLEAN_RATE  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402
from vdnif_addon.threads import use_threads  # noqa: E402
from vdnif_addon.training.fit import fit_model  # noqa: E402

FORMAT = "vdnif-time-to-clean"
"""The figures' format mark: the output rule lets ``--json`` replace only the tool's own file."""


def parse_setting(item):
    """``KEY=VALUE`` (VALUE as JSON, else as text) -> (key, value)."""
    key, equals, value = item.partition("=")
    if not equals or not key:
        raise VDNIFError(f"setting '{item}' is not KEY=VALUE")
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, help="dataset folder written by 'dataset'")
    parser.add_argument("--scene", required=True, help="the demo scene the dataset is of")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a TrainConfig or NetworkConfig field (JSON value)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    parser.add_argument("--seed", type=int, default=0,
                        help="the training pose seed whose unseen poses are evaluated")
    parser.add_argument("--repeats", type=int, default=1,
                        help="trainings timed (the median is reported); the last is evaluated")
    parser.add_argument("--json", required=True, help="write the figures here")
    parser.add_argument("--model", type=pathlib.Path,
                        help="keep the evaluated model here (default: discarded)")
    args = parser.parse_args()
    check_output_file(args.json, "--json", "json")        # the output rule, before the training
    if args.model is not None:
        check_output_file(args.model, "--model", "model")
    if args.repeats < 1:
        raise VDNIFError(f"--repeats must be at least 1, got {args.repeats}")
    overrides = dict(parse_setting(item) for item in args.set)
    threads = use_threads(args.threads)
    with tempfile.TemporaryDirectory() as scratch:
        model = args.model or pathlib.Path(scratch) / "model.vdnif"
        walls, steps_s = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            result, _ = fit_model(args.data, "proposed", model, overrides)
            walls.append(time.perf_counter() - start)
            steps_s.append(result.seconds)
        history = [(r["step"], (r["validation"] or {}).get("occlusion_accuracy"))
                   for r in result.history]
        report = {"format": FORMAT, "data": args.data, "scene": args.scene, "overrides": overrides,
                  "torch_threads": threads, "status": result.status, "steps": result.steps,
                  "train_s": statistics.median(steps_s), "wall_s": statistics.median(walls),
                  "train_s_runs": steps_s, "wall_s_runs": walls,
                  "occlusion_history": history}
        for name, pose_set in (("dev", "development"), ("test", "test")):
            out = pathlib.Path(scratch) / f"{name}.json"
            subprocess.run([sys.executable, str(ROOT / "vdnif_addon" / "batch.py"), "--",
                            "evaluate", "--model", str(model), "--scene", args.scene,
                            "--poses", "8", "--width", "256", "--height", "256",
                            "--seed", str(args.seed), "--pose-set", pose_set,
                            "--device", "cpu", "--json", str(out)],
                           check=True, stdout=subprocess.DEVNULL)
            figures = json.loads(out.read_text())["vs_true"]
            figures["clean"] = (figures["false_negative_rate"] <= CLEAN_RATE
                                and figures["false_positive_rate"] <= CLEAN_RATE)
            report[name] = figures
    report = stamp(report, with_machine=True)       # training times: the machine's load
    write_json_atomic(args.json, report, "--json", indent=1)
    print(json.dumps({k: report[k] for k in ("status", "steps", "train_s", "wall_s")}))
    for name in ("dev", "test"):
        f = report[name]
        print(f"{name}: holes {100 * f['false_negative_rate']:.2f} %, extras "
              f"{100 * f['false_positive_rate']:.2f} %, distance {f['distance_mae']:.5f}, "
              f"normal {f['normal_error_deg']:.2f} deg, clean {f['clean']}")


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="time_to_clean: error: ")
