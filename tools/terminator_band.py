"""Where the shadow pass's errors lie against the light's angle: evaluates a model as
``evaluate --secondary`` does (the same options, poses and pixels; choose the band on
``--pose-set development``) and counts, per bin of |N.L| (the true reference's normal
towards the light), the pixels where the network and the true reference both hit and the
shadow flips among them (lit in one, shadowed in the other, from each one's own hits). The
flips that a small normal error makes gather where |N.L| is near 0, the terminator; the
cast shadows' flips spread over every angle. Prints the table and, per candidate band width
w, the share of the flips inside |N.L| < w and the false lit and false shadow rates of the
cast shadows outside it (``shading.shadow_split``), and what the visibly different shaded
pixels are (``visible_parts``); ``--json`` writes them with evaluate's own report and the load
average, marked as the tool's (checked by the output rule before the model is read and
written atomically: it replaces only a file the tool wrote).

    python vdnif_addon/batch.py -- train --scene spot --out out/spot.vdnif
    python tools/terminator_band.py --model out/spot.vdnif --scene spot --poses 8 \\
        --width 256 --height 256 --secondary --pose-set development --json band.json
"""

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.inference.shading import (  # noqa: E402
    VISIBLE_STEP,
    display_8bit,
    in_band,
    shadow_split,
)
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.passes import SecondaryPasses  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402

BIN = 0.025
WIDTHS = (0.0, 0.025, 0.05, 0.075, 0.1, 0.15, 0.175, 0.2, 0.3)
FORMAT = "vdnif-terminator-band"
"""The tables' format mark: the output rule lets ``--json`` replace only the tool's own file."""


def band_table(cosines, predicted: SecondaryPasses, reference: SecondaryPasses,
               widths=WIDTHS, step=BIN) -> dict:
    """``bins``: per bin of |N.L| (``cosines``, the reference's, NaN on a miss) of width
    ``step`` up to 1, the pixels where both hit and the shadow flips among them; ``widths``:
    per band width, the share of the flips inside it and ``shadow_split``'s rates."""
    both = predicted.hit & reference.hit
    flips = both & (predicted.lit != reference.lit)
    angle = np.abs(np.nan_to_num(cosines, nan=2.0))
    edges = np.arange(0.0, 1.0 + step / 2, step)
    index = np.clip(np.digitize(angle, edges) - 1, 0, len(edges) - 2)
    bins = [{"low": float(edges[i]), "high": float(edges[i + 1]),
             "pixels": int((both & (index == i)).sum()),
             "flips": int((flips & (index == i)).sum())} for i in range(len(edges) - 1)]
    rows = []
    for width in widths:
        band = in_band(cosines, width)
        rows.append({"width": width,
                     "flips_inside": float((flips & band).sum() / max(flips.sum(), 1)),
                     "pixels_inside": float((both & band).sum() / max(both.sum(), 1)),
                     **shadow_split(predicted, reference, band)})
    return {"pixels": int(both.sum()), "flips": int(flips.sum()), "bins": bins,
            "widths": rows}


def visible_parts(shaded, hits, secondary) -> dict:
    """Of the pixels whose shaded values differ visibly (``shading.compare_shaded``'s rule),
    the shares over every pixel where the hit masks differ (a hole or an extra), where both
    hit and the shadow flips, and where both hit with the same shadow (the normal's, the
    albedo's and the AO's errors): {"mask", "shadow_flip", "same_shadow"}."""
    steps = np.abs(display_8bit(shaded["predicted"]).astype(np.int16)
                   - display_8bit(shaded["true"]).astype(np.int16)).max(-1)
    visible = steps > VISIBLE_STEP
    both = hits["predicted"] & hits["true"]
    flip = both & (secondary["predicted"].lit != secondary["true"].lit)
    return {"mask": float((visible & (hits["predicted"] != hits["true"])).mean()),
            "shadow_flip": float((visible & flip).mean()),
            "same_shadow": float((visible & both & ~flip).mean())}


def main():
    own = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], add_help=False)
    own.add_argument("--json", type=pathlib.Path, help="write the tables here")
    known, rest = own.parse_known_args()
    if known.json is not None:          # the output rule, before the model is read
        check_output_file(known.json, "--json", "json")
    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.model_commands import evaluated
    from vdnif_addon.cli.options import validate_arguments

    args = build_parser().parse_args(["evaluate", *rest])
    validate_arguments(args)
    if not args.secondary:
        raise VDNIFError("give --secondary: the band splits the shadow pass's errors")
    report, views, _ = evaluated(args)
    names = ("predicted", "true")
    secondary = {name: SecondaryPasses.concatenate([v["secondary"][name] for v in views])
                 for name in names}
    table = band_table(np.concatenate([v["cosines"]["true"] for v in views]),
                       secondary["predicted"], secondary["true"])
    table["visible"] = visible_parts(
        {name: np.concatenate([v["shaded"][name] for v in views]) for name in names},
        {name: np.concatenate([v[name].hit for v in views]) for name in names}, secondary)
    print(f"visible steps: {100 * report['vs_true']['shaded_visible_rate']:.2f} % of the "
          "pixels: " + ", ".join(f"{name.replace('_', ' ')} {100 * share:.2f} %"
                                 for name, share in table["visible"].items()))
    print(f"{report['object']}: {table['flips']:,} shadow flips of {table['pixels']:,} "
          f"pixels where both hit, {args.pose_set} poses")
    print("  |N.L| bin      pixels  flips  flip rate")
    for row in table["bins"]:
        if row["pixels"]:
            print(f"  {row['low']:.3f}-{row['high']:.3f} {row['pixels']:8,} {row['flips']:6,} "
                  f"{100 * row['flips'] / row['pixels']:8.2f} %")
    print("  width  flips inside  pixels inside  cast false lit  cast false shadow")
    for row in table["widths"]:
        print(f"  {row['width']:.3f} {100 * row['flips_inside']:11.1f} % "
              f"{100 * row['pixels_inside']:12.1f} % {_percent(row['shadow_false_lit_rate_cast'])}"
              f" {_percent(row['shadow_false_shadow_rate_cast'])}")
    if known.json is not None:
        import os

        write_json_atomic(known.json, stamp({"format": FORMAT, "object": report["object"],
                                             "pose_set": args.pose_set, "poses": report["poses"],
                                             "width": report["width"],
                                             "height": report["height"],
                                             "model": str(args.model), "load": os.getloadavg(),
                                             **table, "report": report}, with_machine=True),
                          "--json", indent=1)


def _percent(share):
    return "     n/a" if share is None else f"{100 * share:13.2f} %"


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=VDNIFError, prefix="terminator_band: error: ")
