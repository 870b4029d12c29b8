"""Numbers as every summary writes them, "n/a" where there is none: the batch commands' lines,
the panel's metrics line and the studies' tables."""

from __future__ import annotations

import re


def value(number: float | None, digits: int = 4) -> str:
    """A number with ``digits`` significant digits, "n/a" for None."""
    return "n/a" if number is None else f"{number:.{digits}g}"


def percent(share: float | None, digits: int = 3) -> str:
    """A share in [0, 1] as a percentage, "n/a" for None."""
    return "n/a" if share is None else f"{100 * share:.{digits}g} %"


_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u200b-\u200f\u202a-\u202e\u2066-\u2069]")


def printable(text: str) -> str:
    """``text`` with its control characters written as escapes (``\\x1b``): a name from a
    user's file (an object's, a path) printed to a terminal cannot move the cursor, recolour
    or hide the line, nor reorder it (bidirectional overrides)."""
    return _CONTROL.sub(lambda match: f"\\x{ord(match.group()):02x}" if ord(match.group())
                        < 0x100 else f"\\u{ord(match.group()):04x}", text)


def article(word: str) -> str:
    """``word`` with "a" or "an" before it, by its first letter's sound as spelled."""
    return f"{'an' if word[:1].lower() in 'aeiou' else 'a'} {word}"


def metrics_line(m: dict) -> str:
    """One line of an evaluation's metrics, as the batch commands and the panel print it:
    distance error in object units and voxels, normal error, the hit-mask metrics and the
    scene's optional metrics ("n/a" where the scene has nothing to predict: one material
    without texture, DESIGN section 10)."""
    voxels = m.get("distance_mae_voxels")
    psnr, accuracy = m.get("albedo_psnr"), m.get("material_accuracy")
    extra = (f", albedo PSNR {value(psnr)}{'' if psnr is None else ' dB'}"
             f", material accuracy {percent(accuracy)}")
    return (f"distance MAE {value(m['distance_mae'])} object units"
            + ("" if voxels is None else f" ({value(voxels)} voxels)")
            + f", normal error {value(m['normal_error_deg'])} deg, hit IoU "
            f"{value(m['hit_iou'])}, false negatives {percent(m.get('false_negative_rate'))}"
            f", false positives {percent(m.get('false_positive_rate'))}{extra}")


def speed_line(report: dict) -> str:
    """The neural render's rays/s of an evaluation report, or n/a with the reason
    (``inference.metrics.speed_withheld``: only models that predict hits have a speed)."""
    speed = report["timings"].get("render_rays_per_s")
    if speed is not None:
        return f"{speed:,.0f} rays/s"
    return f"n/a ({report['speed_withheld']})" if report.get("speed_withheld") else "n/a"


EXACT_PATH = "exact path (Warp's BVH of the deformed mesh, refit per pose)"
"""What the exact path is, in the words every speed line uses: the ray casts the extension
ships as the true reference, timed on the same rays as the network."""
EMBREE_NOTE = ("Embree, which the extension does not ship, is faster than Warp's BVH: "
               "docs/performance.md, 'Side by side with the classical baselines'")
"""Where the stronger classical path is measured (said wherever the exact path's speed is)."""


def exact_speed_line(report: dict) -> str:
    """The exact path's rays/s on the rays the network's speed was measured on
    (``timings.exact_rays_per_s``; "n/a" in a report without it)."""
    exact = report["timings"].get("exact_rays_per_s")
    return f"{EXACT_PATH} {'n/a' if exact is None else f'{exact:,.0f} rays/s'}"


def secondary_line(m: dict) -> str:
    """The AO and shadow errors of an evaluation's metrics, from the network's own hits and
    (in brackets) from the true ones (``metrics.compare_secondary``)."""
    return (f"AO MAE {value(m['ao_mae'])} ({value(m['ao_mae_true_hit'])}), shadow false lit "
            f"{percent(m['shadow_false_lit_rate'])} "
            f"({percent(m['shadow_false_lit_rate_true_hit'])}), false shadow "
            f"{percent(m['shadow_false_shadow_rate'])} "
            f"({percent(m['shadow_false_shadow_rate_true_hit'])})")


def shaded_line(m: dict) -> str:
    """The shaded image's errors of an evaluation's metrics (``shading.compare_shaded``: its
    PSNR on linear values, peak 1, and the share of pixels a user sees differ) and its shadow
    rates split at the terminator band (``shading.shadow_split``)."""
    psnr = m["shaded_psnr"]
    return (f"shaded PSNR {value(psnr)}{'' if psnr is None else ' dB'}, visible steps "
            f"{percent(m['shaded_visible_rate'])}; cast shadows false lit "
            f"{percent(m['shadow_false_lit_rate_cast'])}, false shadow "
            f"{percent(m['shadow_false_shadow_rate_cast'])}; at the terminator false lit "
            f"{percent(m['shadow_false_lit_rate_terminator'])}, false shadow "
            f"{percent(m['shadow_false_shadow_rate_terminator'])}")
