"""Speed/accuracy presets: the Pareto front of a measured sweep, and the fast / balanced /
accurate settings derived from it (written by the ``bench`` command, read by the panel)."""

from __future__ import annotations

import json
import pathlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import VDNIFError
from .metrics import speed_withheld

PRESETS_FILE = pathlib.Path(__file__).with_name("presets.json")
PRESET_NAMES = ("fast", "balanced", "accurate")
SETTINGS = ("resolution", "levels", "log2_table_size", "pe_bands", "width", "steps")
PRESET_ERROR = "common_vs_true_distance_mae"
"""The error the presets' front minimizes and each preset's ``measured`` holds: distance MAE
against the true reference (object units) over the common pixel set of the sweep's points
that predict hits (DESIGN section 10). A presets file names it as its ``error``."""


def pareto_front(error: Sequence[float], cost: Sequence[float]) -> list[int]:
    """Indices of the points no other point beats on both ``error`` and ``cost`` (both
    lower is better; ties keep the first), ordered by increasing cost."""
    error, cost = np.asarray(error, np.float64), np.asarray(cost, np.float64)
    order = np.lexsort((error, cost))
    front, best = [], np.inf
    for index in order:
        if error[index] < best:
            front.append(int(index))
            best = error[index]
    return front


def derive_presets(points: Sequence[dict[str, Any]], error_key: str = "error",
                   speed_key: str = "render_rays_per_s",
                   iou_key: str = "vs_true_hit_iou") -> dict[str, dict[str, Any]]:
    """{fast, balanced, accurate} from the sweep ``points`` (dicts with SETTINGS, the error,
    the speed and the hit IoU against the true reference): on the front of error vs
    1/speed of the points that predict hits (metrics.speed_withheld), the fastest point,
    the most accurate one, and the one closest to the ideal corner in normalized log space
    (the knee)."""
    usable = [p for p in points if p.get(error_key) is not None and p.get(speed_key)
              and speed_withheld(p.get(iou_key)) is None]
    if not usable:
        raise VDNIFError("no sweep point has both an error and a speed of a model that "
                         "predicts hits: cannot derive presets")
    error = np.array([p[error_key] for p in usable])
    cost = 1.0 / np.array([p[speed_key] for p in usable])
    front = pareto_front(error, cost)
    log_error, log_cost = np.log(error[front]), np.log(cost[front])

    def unit(values):
        span = values.max() - values.min()
        return (values - values.min()) / span if span > 0 else np.zeros_like(values)

    knee = front[int(np.argmin(np.hypot(unit(log_error), unit(log_cost))))]
    chosen = {"fast": front[0], "balanced": knee, "accurate": front[-1]}
    return {name: {**{key: usable[i][key] for key in SETTINGS},
                   "measured": {error_key: usable[i][error_key],
                                speed_key: usable[i][speed_key]}}
            for name, i in chosen.items()}


def describe_preset(name: str, preset: dict[str, Any]) -> str:
    """One line for the panel's tooltip and the Apply Preset report: ``preset``'s settings in
    the panel's words and what ``bench`` measured with them (PRESET_ERROR, rays/s)."""
    measured = preset["measured"]
    speed = measured.get("render_rays_per_s")
    return (f"{name.title()}: resolution {preset['resolution']}, {preset['levels']} hash-grid "
            f"levels of 2^{preset['log2_table_size']} entries, {preset['pe_bands']} "
            f"positional-encoding bands, width {preset['width']}, {preset['steps']:,} steps; "
            f"bench measured a distance error of {measured[PRESET_ERROR]:.3g} object units"
            + (f" and {speed:,.0f} rays/s" if speed else ""))


def load_presets(path: str | pathlib.Path | None = None) -> dict[str, dict[str, Any]]:
    """The presets written by ``bench`` (default: the shipped file); a missing or malformed
    file, or one whose presets measured another error than PRESET_ERROR (an older bench's),
    raises VDNIFError."""
    path = pathlib.Path(path or PRESETS_FILE)
    try:
        data = json.loads(path.read_text())
        presets = data["presets"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise VDNIFError(f"presets file '{path}' cannot be read: {exc}") from None
    if not isinstance(presets, dict) or set(presets) != set(PRESET_NAMES) or any(
            not isinstance(preset, dict) or set(SETTINGS) - set(preset)
            or not isinstance(preset.get("measured"), dict)
            or PRESET_ERROR not in preset["measured"] for preset in presets.values()):
        raise VDNIFError(f"presets file '{path}' does not hold {', '.join(PRESET_NAMES)} "
                         f"with {', '.join(SETTINGS)} and a measured {PRESET_ERROR}")
    if data.get("error") != PRESET_ERROR:
        raise VDNIFError(f"presets file '{path}' measures its presets by "
                         f"{data.get('error')!r}, not {PRESET_ERROR!r}: run bench again")
    return presets
