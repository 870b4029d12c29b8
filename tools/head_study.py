"""How a variant's settings change what its heads learn: trains each named run on one dataset
folder, the same steps and seed, and prints the held-out poses' validation figures (local
distance error in voxels, normal error, segment occlusion accuracy, and the albedo loss and
material accuracy where the object has them) and the loss weighting's
learned log-variances. Cheaper than an experiment (no rendering): it measures the heads,
not the passes.

    python vdnif_addon/batch.py -- dataset --scene arm --out out/arm-data
    python tools/head_study.py --data out/arm-data --steps 3000 deformed proposed \\
        proposed:distance_mode=log1p proposed:lr_weighting=0.01

A run is ``VARIANT[:KEY=VALUE[,KEY=VALUE...]]`` with NetworkConfig or TrainConfig fields.
"""

import argparse
import json
import pathlib
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.settings import DEFAULT_DEVICE, DEVICES  # noqa: E402
from vdnif_addon.training.fit import fit_model  # noqa: E402

FIGURES = ("distance_mae_voxels", "normal_error_deg", "occlusion_accuracy", "loss/albedo",
           "material_accuracy")
"""Printed where the run has them: the albedo (L1 loss over hits) and material figures need
those heads."""


def parse_run(text):
    """(variant, overrides) of ``VARIANT[:KEY=VALUE,...]``; values are read as JSON where
    they parse (numbers), else kept as text (names)."""
    variant, _, settings = text.partition(":")
    overrides = {}
    for item in filter(None, settings.split(",")):
        key, equals, value = item.partition("=")
        if not equals:
            raise VDNIFError(f"run '{text}': '{item}' is not KEY=VALUE")
        try:
            overrides[key] = json.loads(value)
        except json.JSONDecodeError:
            overrides[key] = value
    return variant, overrides


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=pathlib.Path, required=True)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", choices=DEVICES, default=DEFAULT_DEVICE)
    parser.add_argument("runs", nargs="+", metavar="VARIANT[:KEY=VALUE,...]")
    args = parser.parse_args()
    runs = [parse_run(text) for text in args.runs]
    with tempfile.TemporaryDirectory() as scratch:
        for text, (variant, overrides) in zip(args.runs, runs):
            settings = dict(overrides, steps=args.steps, seed=args.seed, device=args.device)
            result, _ = fit_model(args.data, variant, pathlib.Path(scratch) / "model.vdnif",
                                  settings)
            last = result.history[-1]["validation"] or {}
            figures = ", ".join(f"{name} {last[name]:.4g}" for name in FIGURES if name in last)
            weights = ", ".join(f"{task} {s:.2f}"
                                for task, s in result.history[-1]["log_variances"].items())
            print(f"{text}: {figures}; log-variances: {weights or 'none (fixed)'}", flush=True)


if __name__ == "__main__":
    try:
        main()
    except VDNIFError as error:
        sys.exit(f"head_study: error: {error}")
