"""How much of a model's error on the pixels where it and the reference both hit comes from
hits on another surface: evaluates a model as ``evaluate`` does (the same options, the same
poses and pixels) and splits those pixels into the ones whose predicted hit lies more than
``--voxels`` voxels from the reference's along the ray (a missed first surface with the ray
going on to one behind it, or a false hit in front of it: a hole or an extra that the hit
mask cannot show) and the rest. Prints, against the true and the embedded reference, their
share of the pixels, of the distance error and of the albedo's squared error, and the
figures with and without them; and the same for the embedded reference against the true
one, the voxel embedding's own share.

    python vdnif_addon/batch.py -- train --scene spot --out out/spot.vdnif
    python tools/wrong_surface.py --model out/spot.vdnif --scene spot --poses 8 \\
        --width 256 --height 256
"""

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.inference.metrics import compare  # noqa: E402
from vdnif_addon.passes import Passes  # noqa: E402

FIGURES = ("distance_mae", "normal_error_deg", "albedo_psnr", "material_accuracy")


def wrong_surface(predicted: Passes, reference: Passes, voxel_size: float, voxels: float,
                  object_size: float, heads: dict) -> dict:
    """Where ``predicted`` and ``reference`` both hit: ``pixels``, ``wrong`` (those whose
    distances differ by more than ``voxels`` x ``voxel_size``), ``distance_share`` and
    ``albedo_share`` (their shares of the summed |distance error| and of the albedo's summed
    squared error; None where there is none), and ``all`` and ``rest``: ``metrics.compare``
    over every such pixel and over all but the wrong ones."""
    both = predicted.hit & reference.hit
    error = np.abs(predicted.distance - reference.distance)
    wrong = both & (error > voxels * voxel_size)
    squared = ((np.clip(predicted.albedo, 0, 1) - np.clip(reference.albedo, 0, 1)) ** 2).sum(1)

    def share(values):
        total = values[both].sum()
        return float(values[wrong].sum() / total) if total > 0 else None

    return {
        "pixels": int(both.sum()), "wrong": int(wrong.sum()),
        "distance_share": share(error),
        "albedo_share": share(squared) if heads.get("albedo_psnr") else None,
        "all": compare(predicted, reference, object_size, heads, voxel_size, pixels=both),
        "rest": compare(predicted, reference, object_size, heads, voxel_size,
                        pixels=both & ~wrong),
    }


def main():
    own = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], add_help=False)
    own.add_argument("--voxels", type=float, default=0.5,
                     help="distance difference, in voxels, above which a hit is on another "
                          "surface (default 0.5)")
    known, rest = own.parse_known_args()
    if not 0 < known.voxels < float("inf"):
        raise VDNIFError(f"--voxels must be a positive number of voxels, got {known.voxels}")
    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.model_commands import evaluated
    from vdnif_addon.cli.options import validate_arguments
    from vdnif_addon.inference.evaluation import metric_heads

    args = build_parser().parse_args(["evaluate", *rest])
    validate_arguments(args)
    report, views, captured = evaluated(args)
    heads = metric_heads(captured.mesh)
    # The embedded reference against the true one: what the voxel embedding alone gives,
    # the best a network trained on the embedded ground truth can do against the true one.
    for model, name in (("predicted", "true"), ("predicted", "embedded"), ("embedded", "true")):
        split = wrong_surface(Passes.concatenate([v[model] for v in views]),
                              Passes.concatenate([v[name] for v in views]),
                              report["voxel_size"], known.voxels, captured.mesh.size, heads)
        print(f"{model} vs {name}: {split['wrong']:,} of {split['pixels']:,} pixels "
              f"({100 * split['wrong'] / max(split['pixels'], 1):.2f} %) hit more than "
              f"{known.voxels} voxels from the reference's hit; they carry "
              f"{_percent(split['distance_share'])} of the distance error and "
              f"{_percent(split['albedo_share'])} of the albedo's squared error")
        for figure in FIGURES:
            if split["all"].get(figure) is not None:
                print(f"  {figure}: {split['all'][figure]:.4g} over every pixel, "
                      f"{split['rest'][figure]:.4g} without them")


def _percent(share):
    return "n/a" if share is None else f"{100 * share:.1f} %"


if __name__ == "__main__":
    try:
        main()
    except VDNIFError as error:
        sys.exit(f"wrong_surface: error: {error}")
