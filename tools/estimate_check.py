"""How close the estimate of a run (the panel's *Estimate Disk and Time*, the sample that
``dataset`` measures before it starts) is to the run: per scene, measures the estimate and
then, back to back in the same process and conditions, generates the dataset and trains as
``train --scene`` does, and prints estimate against actual for the dataset's size and time
and the training's time (wall seconds, data loading, validation and saving included).

    python tools/estimate_check.py --json docs/results/estimate-check.json \\
        --scene arm --scene lattice --scene spot --scene bunny [-- TRAIN OPTIONS]

Anything after ``--`` is passed to the ``train`` command's parser (``--poses 16``,
``--steps 1000``, ``--resolution 24`` ...), the same for every scene.

``--json`` is rewritten atomically after each scene, marked as the tool's and checked by the
output rule before the first scene starts: it replaces only a file the tool wrote.
"""

import argparse
import pathlib
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402

FORMAT = "vdnif-estimate-check"
"""The figures' format mark: the output rule lets ``--json`` replace only the tool's own file."""


def check_scene(scene, train_options):
    """Estimate and actual figures of ``train --scene scene`` with ``train_options``."""
    import torch

    from vdnif_addon.blender.steps import training_capture, variant_capture, variant_dataset
    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.options import load_posed_scene, network_overrides
    from vdnif_addon.model.variants import choose_variant, variant_config
    from vdnif_addon.posed import estimate as estimates
    from vdnif_addon.training.fit import fit_model

    # the recipe's fixed resolution unless given: the one its table was measured at
    resolution = [] if "--resolution" in train_options else ["--resolution", "recipe"]
    args = build_parser().parse_args(["train", "--scene", scene, *resolution, *train_options])
    obj, spec = load_posed_scene(args)
    captured = training_capture(obj, args.resolution, spec)    # as train captures it
    variant, _ = choose_variant(args.variant, captured.mode == "static")
    overrides = network_overrides(args)
    with tempfile.TemporaryDirectory(prefix="vdnif-estimate-") as scratch:
        scratch = pathlib.Path(scratch)
        start = time.perf_counter()
        sample, rays_per_pose = variant_capture(captured, variant, args.rays_per_pose)
        rates = estimates.measure(obj, sample, variant, overrides, scratch / "sample",
                                  args.seed)
        config = variant_config(variant, **overrides).train
        figures = estimates.estimate(rates, len(sample.poses), rays_per_pose, config)
        steps_only = config.steps * config.batch_size / rates["samples_per_s"]
        estimate_s = time.perf_counter() - start
        start = time.perf_counter()
        header = variant_dataset(obj, captured, variant, scratch / "data", args.rays_per_pose,
                                 args.seed)
        dataset_s = time.perf_counter() - start
        size = sum(path.stat().st_size for path in (scratch / "data").iterdir())
        start = time.perf_counter()
        result, _ = fit_model(scratch / "data", variant, scratch / "model.vdnif", overrides)
        train_s = time.perf_counter() - start
    actual = {"bytes": size, "segments": header.counts.segments, "dataset_s": dataset_s,
              "train_s": train_s, "train_steps_s": result.seconds, "steps": result.steps,
              "status": result.status}
    estimated = {key: figures[key] for key in ("bytes", "segments", "dataset_s", "train_s")}
    return {"scene": scene, "variant": variant, "resolution": args.resolution,
            "poses": len(captured.poses), "rays_per_pose": args.rays_per_pose,
            "steps": overrides["steps"], "batch_size": overrides["batch_size"],
            "torch_threads": torch.get_num_threads(), "estimate_seconds": estimate_s,
            "estimate": estimated, "actual": actual, "rates": figures["rates"],
            "steps_only_train_s": steps_only, "actual_timings": result.timings,
            "ratio": {key: actual[key] / estimated[key] for key in estimated}}


def main():
    argv = sys.argv[1:]
    train_options = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", action="append", required=True,
                        help="a demo scene (repeat for several)")
    parser.add_argument("--json", type=pathlib.Path, help="write the figures here")
    args = parser.parse_args(argv)
    if args.json is not None:
        check_output_file(args.json, "--json", "json")      # the output rule, before any scene
    from vdnif_addon.threads import use_threads

    use_threads(None)                  # as the batch commands do before they run
    rows = []
    for scene in args.scene:
        row = check_scene(scene, train_options)
        rows.append(row)
        ratio = row["ratio"]
        print(f"{scene}: dataset {row['estimate']['bytes'] / 1e6:.1f} MB estimated, "
              f"{row['actual']['bytes'] / 1e6:.1f} MB actual (x{ratio['bytes']:.2f}); "
              f"dataset {row['estimate']['dataset_s']:.1f} s / {row['actual']['dataset_s']:.1f} s"
              f" (x{ratio['dataset_s']:.2f}); training {row['estimate']['train_s']:.1f} s / "
              f"{row['actual']['train_s']:.1f} s (x{ratio['train_s']:.2f})", flush=True)
        if args.json is not None:
            write_json_atomic(args.json, stamp({"format": FORMAT, "command": " ".join(sys.argv),
                                                "rows": rows}, with_machine=True),
                              "--json", indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=VDNIFError, prefix="estimate_check: error: ")
