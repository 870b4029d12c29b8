"""The Pareto front of a measured speed/accuracy sweep and the fast / balanced / accurate
presets derived from it, less those not measurably faster than a more accurate one (the
``bench`` command writes them; ``presets.py`` reads them)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import VDNIFError
from ..inference.metrics import speed_withheld
from ..presets import PRESET_NAMES, SETTINGS, SPEED_ROUNDS


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


def front_distance(error: Sequence[float], cost: Sequence[float],
                   front: Sequence[int]) -> np.ndarray:
    """Per point, how far it lies from ``front`` (indices of ``pareto_front``): the smallest
    log factor by which its error and its cost would both have to shrink for no front point
    to be at least as good on both (the additive epsilon indicator in log space); 0 on the
    front."""
    log_error, log_cost = np.log(np.asarray(error, np.float64)), np.log(
        np.asarray(cost, np.float64))
    distance = np.zeros(len(log_error))
    for f in front:
        beaten = (log_error >= log_error[f]) & (log_cost >= log_cost[f])
        gain = np.minimum(log_error - log_error[f], log_cost - log_cost[f])
        distance = np.where(beaten, np.maximum(distance, gain), distance)
    return distance


def speed_range(point: dict[str, Any]) -> tuple[float, float] | None:
    """(slowest, fastest) of ``point``'s timing rounds (its SPEED_ROUNDS), None where it has
    none (a sweep point of an older bench.json, a preset of an older presets file, a point
    whose speed is withheld)."""
    rounds = point.get(SPEED_ROUNDS)
    return (min(rounds), max(rounds)) if rounds else None


def round_ratios(point: dict[str, Any], other: dict[str, Any]) -> list[float] | None:
    """``point``'s speed over ``other``'s in each timing round (SPEED_ROUNDS), None where
    either has none or their counts differ (not rounds of one sweep)."""
    ours, theirs = point.get(SPEED_ROUNDS), other.get(SPEED_ROUNDS)
    if not ours or not theirs or len(ours) != len(theirs):
        return None
    return [a / b for a, b in zip(ours, theirs)]


def measurably_faster(point: dict[str, Any], other: dict[str, Any]) -> bool:
    """Whether ``point``'s speed differs measurably from ``other``'s, and is the faster: it
    is faster in every timing round (``round_ratios`` all above 1). A point's rounds spread
    widely on a shared VM (the sweep's section of docs/performance.md says how widely), so
    ranges of rounds overlap where one point is faster in every round; if neither were
    faster, each round would favour either as a coin toss, and all of n rounds one way would
    happen once in 2^n. Points without rounds of the same sweep cannot be shown to differ:
    False. Two points differ measurably when either is measurably faster than the other."""
    ratios = round_ratios(point, other)
    return ratios is not None and all(ratio > 1 for ratio in ratios)


def derive_presets(points: Sequence[dict[str, Any]], error_key: str = "error",
                   speed_key: str = "render_rays_per_s", iou_key: str = "vs_true_hit_iou"
                   ) -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
    """(presets, dropped): ``pick_presets``'s fast, balanced and accurate, less each that is
    not measurably faster (``measurably_faster``) than the next more accurate one kept, which
    it would trade a larger error for nothing measurable; ``dropped`` gives each dropped
    name's reason in one line. Accurate is always kept, and a sweep without timing rounds
    (an older bench.json) keeps it alone: no speed of it can be shown to differ."""
    picked = pick_presets(points, error_key, speed_key, iou_key)
    kept, dropped = [], {}
    for name in reversed(PRESET_NAMES):         # from the most accurate to the fastest
        if kept and not measurably_faster(picked[name]["measured"],
                                          picked[kept[-1]]["measured"]):
            dropped[name] = _not_faster(picked[name]["measured"], kept[-1],
                                        picked[kept[-1]]["measured"], speed_key)
        else:
            kept.append(name)
    return ({name: picked[name] for name in PRESET_NAMES if name in kept},
            {name: dropped[name] for name in PRESET_NAMES if name in dropped})


def _not_faster(measured: dict[str, Any], slower: str, other: dict[str, Any],
                speed_key: str) -> str:
    """Why a preset measured ``measured`` is dropped against the more accurate ``slower``,
    measured ``other``: one line with the rounds it was faster in and the range of the
    round-by-round ratio, or the medians where either has no rounds."""
    ratios = round_ratios(measured, other)
    if ratios is None:
        return (f"not shown faster than {slower.title()}: no timing rounds recorded "
                f"({measured[speed_key]:,.0f} rays/s against {other[speed_key]:,.0f}, "
                "medians)")
    faster = sum(ratio > 1 for ratio in ratios)
    return (f"measured no faster than {slower.title()}: faster in {faster} of {len(ratios)} "
            f"timing rounds, {min(ratios):.2f}-{max(ratios):.2f}x round by round")


def pick_presets(points: Sequence[dict[str, Any]], error_key: str = "error",
                 speed_key: str = "render_rays_per_s",
                 iou_key: str = "vs_true_hit_iou") -> dict[str, dict[str, Any]]:
    """{fast, balanced, accurate}: three distinct sweep ``points`` (dicts with SETTINGS, the
    error, the speed, its timing rounds SPEED_ROUNDS where they were kept, and the hit IoU
    against the true reference), each as a preset (``_preset``). On the front of error vs
    1/speed of the points that predict hits (metrics.speed_withheld): the fastest point, the
    most accurate one, and between them the knee, the interior point closest to the ideal
    corner in log space normalized over the front. A front of two points has no interior:
    balanced is then the point nearest the front (``front_distance``). A front of one point,
    or two points and no other, raises VDNIFError."""
    usable = [p for p in points if p.get(error_key) is not None and p.get(speed_key)
              and speed_withheld(p.get(iou_key)) is None]
    if not usable:
        raise VDNIFError("no sweep point has both an error and a speed of a model that "
                         "predicts hits: cannot derive presets")
    error = np.array([p[error_key] for p in usable])
    cost = 1.0 / np.array([p[speed_key] for p in usable])
    front = pareto_front(error, cost)
    if len(front) == 1:
        raise VDNIFError(f"one sweep point of {len(usable)} is both the fastest and the most "
                         "accurate: fast, balanced and accurate would not differ; widen the "
                         "sweep")
    if len(front) >= 3:
        log_error, log_cost = np.log(error[front]), np.log(cost[front])

        def unit(values):
            return (values - values.min()) / (values.max() - values.min())

        corner = np.hypot(unit(log_error), unit(log_cost))
        balanced = front[1 + int(np.argmin(corner[1:-1]))]
    elif len(usable) == 2:
        raise VDNIFError("the sweep has two points that predict hits, fast and accurate, and "
                         "no third for balanced; widen the sweep")
    else:
        # Two front points have nothing between them: every other point is beaten on both
        # error and speed by one of them. Refusing would leave the panel without presets
        # after a sweep of hours, and repeating fast or accurate would offer one setting
        # under two names; the point the smallest gain would put on the front is the
        # closest a measured setting comes to lying between them, and the panel says which
        # preset beats it (presets.describe_preset).
        distance = front_distance(error, cost, front)
        distance[front] = np.inf
        balanced = int(np.argmin(distance))
    chosen = dict(zip(PRESET_NAMES, (front[0], balanced, front[-1])))
    return {name: _preset(usable[i], error_key, speed_key) for name, i in chosen.items()}


def _preset(point: dict[str, Any], error_key: str, speed_key: str) -> dict[str, Any]:
    """Sweep ``point`` as a preset: its SETTINGS and what it ``measured``, its error, its
    speed and that speed's timing rounds where the point kept them."""
    measured = {error_key: point[error_key], speed_key: point[speed_key]}
    if point.get(SPEED_ROUNDS):
        measured[SPEED_ROUNDS] = point[SPEED_ROUNDS]
    return {**{key: point[key] for key in SETTINGS}, "measured": measured}
