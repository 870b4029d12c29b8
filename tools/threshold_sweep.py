"""The occlusion threshold on rendered frames: one trained model rendered at each occlusion
threshold that training's calibration could choose, on the development and the test poses,
with holes and extras (the clean rule's two rates) against the true and the embedded
references. For the development poses it marks the threshold where the larger of holes and
extras against the true reference is least, as training's calibration chooses on its views
(``settings.OCCLUSION_CALIBRATION``; ties to the default 0.5), and gives that threshold's
figures on the test poses; the stored (calibrated) threshold, 0.5 and
any given with ``--also`` are always swept. The candidate threshold stays the model's,
lowered to the occlusion threshold where it lies above it, as the render requires.

    python tools/threshold_sweep.py run --model M.vdnif --mesh C.glb --pose-source frames \\
        --json out/threshold-sweep.json
    python tools/threshold_sweep.py run --model out/arm.vdnif --scene arm --step 0.04 \\
        --json out/arm-sweep.json
    python tools/threshold_sweep.py table out/threshold-sweep.json

``run`` takes the scene and pose options of ``batch.py -- evaluate`` (``--scene``, ``--mesh``,
``--pose-source``, ``--poses``, ``--seed``, ``--width``, ``--height``, ``--device``, ...),
by default 8 poses per set at 256x256 on the CPU. ``--step`` (default 0.02, the calibration's
grid) sweeps every multiple of it in the calibration's range 0.1..0.9; a coarser step must be
a multiple of 0.02. Each threshold renders the poses again with both references, as
``evaluate`` does (one runtime path): the skinned character's 82 renders (41 thresholds, 8
poses per set at 256x256) took 142 s on one thread of a loaded 2-core Xeon. ``table``
prints the Markdown table of a run's JSON: 0.5, the stored threshold and the development
optimum with its neighbours. Files written before the optimum followed the calibration's rule
lack ``development_rule``: their optimum is the least sum of the two. ``run`` refuses a
``--json`` that is its model or a file it did not write, before any work, and writes it
atomically.
"""

import argparse
import hashlib
import json
import os
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from vdnif_addon.errors import VDNIFError  # noqa: E402

DEFAULTS = ["--poses", "8", "--width", "256", "--height", "256", "--device", "cpu"]
# evaluate's options that the sweep sets itself or that have no meaning for it
REFUSED = ("--pose-set", "--rest-pose", "--out", "--secondary")
FORMAT = "vdnif-threshold-sweep"
"""The JSON's format mark: the output rule lets the tool replace only its own files."""
DIGITS = 6          # thresholds are rounded to this many decimals (0.76, not 0.7600000001)
NEIGHBOURS = 3      # the table's rows on each side of the development optimum


def thresholds(step, low, high, bins, extra=()):
    """The occlusion thresholds swept: the multiples of ``step`` from ``low`` to ``high``
    (``step`` a multiple of 1 / ``bins``, the calibration's grid), with the ``extra`` ones
    (the stored threshold, 0.5), ascending and rounded to DIGITS decimals."""
    units = step * bins
    if not (units >= 1 and abs(units - round(units)) < 1e-9):
        raise VDNIFError(f"--step {step:g} is not a positive multiple of the calibration's "
                         f"grid step {1 / bins:g}")
    units = round(units)
    first, last = round(low * bins), round(high * bins)
    swept = {round(k / bins, DIGITS) for k in range(first, last + 1, units)}
    return sorted(swept | {round(float(t), DIGITS) for t in extra})


def best(rows, default):
    """The row of ``rows`` (one pose set's) whose larger of holes and extras against the true
    reference is least, the rule of training's calibration; ties go to the occlusion
    threshold nearest ``default``."""
    def errors(row):
        true = row["vs_true"]
        return max(true["false_negative_rate"], true["false_positive_rate"])

    return min(rows, key=lambda row: (errors(row), abs(row["occlusion"] - default)))


def clean(row, rate):
    """Whether ``row``'s holes and extras against the true reference are each at most
    ``rate`` (the clean rule)."""
    true = row["vs_true"]
    return true["false_negative_rate"] <= rate and true["false_positive_rate"] <= rate


def summarize(rows, default, rate):
    """The development optimum (``best``) and its test figures, and the development poses'
    clean thresholds, from the sweep's ``rows`` (both pose sets)."""
    from vdnif_addon.pose_sets import DEVELOPMENT_POSES, TEST_POSES

    development = [r for r in rows if r["pose_set"] == DEVELOPMENT_POSES]
    optimum = best(development, default)
    test = next(r for r in rows if r["pose_set"] == TEST_POSES
                and r["occlusion"] == optimum["occlusion"])
    return {"occlusion": optimum["occlusion"], "development": optimum, "test": test,
            "development_clean": [r["occlusion"] for r in development if clean(r, rate)]}


def table_thresholds(data):
    """The thresholds the Markdown table shows: 0.5, the stored one and the development
    optimum with NEIGHBOURS swept thresholds on each side."""
    swept = sorted({r["occlusion"] for r in data["rows"]})
    at = swept.index(data["development_best"]["occlusion"])
    shown = set(swept[max(at - NEIGHBOURS, 0):at + NEIGHBOURS + 1])
    shown |= {round(data["default_threshold"], DIGITS),
              round(data["stored_thresholds"]["occlusion"], DIGITS)}
    return sorted(shown)


def table(data):
    """The Markdown table of a sweep's JSON ``data``."""
    def cell(row):
        true = row["vs_true"]
        return (f"{100 * true['false_negative_rate']:.3g} % | "
                f"{100 * true['false_positive_rate']:.3g} %")

    rows = {(r["pose_set"], r["occlusion"]): r for r in data["rows"]}
    lines = ["| occlusion threshold | development: holes | extras | test: holes | extras |",
             "| --- | --- | --- | --- | --- |"]
    for threshold in table_thresholds(data):
        notes = [name for name, value in (
            ("stored", data["stored_thresholds"]["occlusion"]),
            ("default", data["default_threshold"]),
            ("development optimum", data["development_best"]["occlusion"]))
            if round(value, DIGITS) == threshold]
        label = f"{threshold:g}" + (f" ({', '.join(notes)})" if notes else "")
        lines.append(f"| {label} | {cell(rows['development', threshold])} | "
                     f"{cell(rows['test', threshold])} |")
    return "\n".join(lines)


def check_options(options):
    """Refuses the evaluate options that the sweep sets itself (REFUSED)."""
    for option in REFUSED:
        if any(item == option or item.startswith(option + "=") for item in options):
            raise VDNIFError(f"{option}: the sweep chooses its poses and writes only --json")


def _figures(metrics):
    keys = ("false_negative_rate", "false_positive_rate", "hit_iou", "distance_mae")
    return {key: metrics.get(key) for key in keys}


def _named(options):
    """Scene options with a mesh or .blend file named by its file name alone."""
    named = list(options)
    for index, item in enumerate(named[:-1]):
        if item in ("--mesh", "--blend"):
            named[index + 1] = pathlib.Path(named[index + 1]).name
    return named


def _model_record(path, metadata):
    """The model's options as its file records them."""
    data = pathlib.Path(path).read_bytes()
    training = metadata.training.to_dict()
    return {"file": pathlib.Path(path).name, "bytes": len(data),
            "sha256": hashlib.sha256(data).hexdigest(), "object": metadata.object,
            "variant": metadata.variant, "resolution": metadata.grid.resolution,
            "corners_follow": metadata.corners_follow, "vdnif_version": metadata.vdnif_version,
            "network": metadata.network_config.to_dict(),
            "dataset": {"poses": metadata.dataset.poses, "segments": metadata.dataset.segments},
            "training": {key: training[key] for key in (
                "status", "steps", "seconds", "validation", "config")}}


def sweep(model_path, options, step, also=()):
    """The sweep's JSON-ready record (module docstring) of the model file ``model_path`` on
    the scene of the evaluate ``options``."""
    from vdnif_addon.blender.steps import evaluate_file, model_capture
    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.options import load_posed_scene, validate_arguments
    from vdnif_addon.inference.metrics import CLEAN_RATE
    from vdnif_addon.kernels.runtime import cpu_description
    from vdnif_addon.model.metadata import Thresholds
    from vdnif_addon.model.model_file import load_model
    from vdnif_addon.model.provenance import stamp
    from vdnif_addon.pose_sets import DEVELOPMENT_POSES, TEST_POSES
    from vdnif_addon.settings import OCCLUSION_CALIBRATION, OCCLUSION_THRESHOLD
    from vdnif_addon.training.validation import THRESHOLD_BINS, THRESHOLD_RANGE

    args = build_parser().parse_args(["evaluate", "--model", str(model_path), *DEFAULTS,
                                      *options])
    validate_arguments(args)
    network, metadata = load_model(args.model)
    stored = metadata.thresholds
    swept = thresholds(step, *THRESHOLD_RANGE, THRESHOLD_BINS,
                       extra=(stored.occlusion, OCCLUSION_THRESHOLD, *also))
    load_start, start = os.getloadavg(), time.perf_counter()
    asked = args.resolution            # load_posed_scene fills in the recipe's without it
    obj, spec = load_posed_scene(args)
    rows = []
    for pose_set in (DEVELOPMENT_POSES, TEST_POSES):
        captured = model_capture(obj, metadata, spec, evaluation=True, count=spec.count,
                                 resolution=asked, pose_set=pose_set)
        for occlusion in swept:
            network.thresholds = Thresholds(occlusion, min(stored.candidate, occlusion))
            report, _ = evaluate_file(obj, captured, args.model, args.width, args.height,
                                      device=args.device, loaded=(network, metadata))
            row = {"pose_set": pose_set, "occlusion": occlusion,
                   "candidate": network.thresholds.candidate,
                   "vs_true": _figures(report["vs_true"]),
                   "vs_embedded": _figures(report["vs_embedded"])}
            row["clean"] = clean(row, CLEAN_RATE)
            rows.append(row)
            true = row["vs_true"]
            print(f"{pose_set} {occlusion:g}: holes {100 * true['false_negative_rate']:.3g} %, "
                  f"extras {100 * true['false_positive_rate']:.3g} %", flush=True)
    record = {
        "format": FORMAT,
        "what": "holes (false_negative_rate) and extras (false_positive_rate) of one model "
                "at each occlusion threshold swept, on development and test poses, against "
                "the true and the embedded references (tools/threshold_sweep.py)",
        "options": _named(options), "model": _model_record(args.model, metadata),
        "stored_thresholds": stored.to_dict(), "default_threshold": OCCLUSION_THRESHOLD,
        "step": step, "clean_rate": CLEAN_RATE, "poses": spec.count, "width": args.width,
        "height": args.height, "device": args.device, "rows": rows,
        "development_best": summarize(rows, OCCLUSION_THRESHOLD, CLEAN_RATE),
        "development_rule": OCCLUSION_CALIBRATION,
        "cpu": cpu_description()[0], "load_average_start": list(load_start),
        "load_average_end": list(os.getloadavg()),
        "seconds": time.perf_counter() - start}
    return stamp(record, with_machine=True)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="sweep a model's occlusion threshold (the other "
                              "options: the scene and poses, as batch.py -- evaluate takes them)")
    run.add_argument("--model", type=pathlib.Path, required=True, help="a trained model file")
    run.add_argument("--step", type=float, default=0.02,
                     help="the thresholds' spacing, a multiple of 0.02 (default 0.02)")
    run.add_argument("--also", type=float, action="append", default=[], metavar="T",
                     help="sweep threshold T as well (repeatable), e.g. another rule's choice")
    run.add_argument("--json", type=pathlib.Path, required=True, metavar="OUT",
                     help="write the sweep here")
    show = commands.add_parser("table", help="the Markdown table of a sweep's JSON")
    show.add_argument("json", type=pathlib.Path)
    args, rest = parser.parse_known_args(argv)
    if args.command == "table":
        if rest:
            parser.error(f"unrecognized arguments: {' '.join(rest)}")
        print(table(json.loads(args.json.read_text())))
        return
    check_options(rest)
    from vdnif_addon.training.validation import THRESHOLD_RANGE

    for value in args.also:
        if not THRESHOLD_RANGE[0] <= value <= THRESHOLD_RANGE[1]:
            raise VDNIFError(f"--also {value:g} is outside the calibration's range "
                             f"{THRESHOLD_RANGE[0]:g}..{THRESHOLD_RANGE[1]:g}")
    if not args.model.is_file():
        raise VDNIFError(f"model file '{args.model}' does not exist")
    from vdnif_addon.output_rule import run_inputs
    from vdnif_addon.safe_io import check_output_file, write_json_atomic
    from vdnif_addon.threads import use_threads

    use_threads(None)                   # as the batch commands do
    with run_inputs([(args.model, "the model file")]):     # the output rule, before any work
        check_output_file(args.json, "--json", "json")
    record = sweep(args.model, rest, args.step, args.also)
    write_json_atomic(args.json, record, "--json", indent=1)
    best_row = record["development_best"]
    print(f"development optimum {best_row['occlusion']:g} (stored "
          f"{record['stored_thresholds']['occlusion']:g}) -> {args.json}")
    print(table(record))


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="threshold_sweep: error: ")
