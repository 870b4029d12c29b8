"""The Pareto front of a measured speed/accuracy sweep and the fast / balanced / accurate
presets derived from it (the ``bench`` command writes them; ``presets.py`` reads them)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import VDNIFError
from ..inference.metrics import speed_withheld
from ..presets import SETTINGS


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
