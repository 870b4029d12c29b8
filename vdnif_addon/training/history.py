"""Training's history as a user reads it: the progress records reduced to step, task losses
and the held-out poses' validation, and their plot (training loss per task solid, the same
loss on the held-out poses dashed, log scale) as an RGB image.

The plot is drawn here with numpy and a small built-in font rather than with matplotlib:
the panel draws it inside Blender, whose Python has no matplotlib, and the batch commands
write the same picture.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from jaxtyping import Float

PLOT_SIZE = (640, 360)          # width, height in pixels
COLORS = {"occlusion": (0.85, 0.33, 0.10), "distance": (0.00, 0.45, 0.74),
          "normal": (0.47, 0.67, 0.19), "albedo": (0.93, 0.69, 0.13),
          "material": (0.49, 0.18, 0.56)}
"""Each task's line colour (a colour-blind-safe palette)."""
_INK, _GRID = np.array((0.1, 0.1, 0.1)), np.array((0.88, 0.88, 0.88))
_LEFT, _RIGHT, _TOP, _BOTTOM = 60, 124, 24, 34       # margins in pixels
# A 5x7 pixel font: per character its 7 rows top first, each 5 bits (16: the left column) as
# two hex digits.
_CHARACTERS = "0123456789abcdefghijklmnopqrstuvwxyz.-+:()/,%_= "
_FONT = """
    0e11131519110e 040c040404040e 0e11010204081f 1f02040201110e 02060a121f0202 1f101e0101110e
    0608101e11110e 1f010204080808 0e11110e11110e 0e11110f01020c 00000e010f110f 1010161911111e
    00000e1010110e 01010d1311110f 00000e111f100e 0609081c080808 000f11110f010e 10101619111111
    04000c0404040e 0200060202120c 10101214181412 0c04040404040e 00001a15151111 00001619111111
    00000e1111110e 00001e111e1010 00000d130f0101 00001619101010 00000e100e011e 08081c08080906
    0000111111130d 00001111110a04 0000111115150a 0000110a040a11 000011110f010e 00001f0204081f
    00000000000c0c 0000001f000000 0004041f040400 000c0c000c0c00 02040808080402 08040202020408
    00010204081000 000000000c0408 18190204081303 0000000000001f 00001f001f0000 00000000000000
""".split()
GLYPHS = {character: np.array([[int(code[2 * row:2 * row + 2], 16) >> (4 - column) & 1
                                 for column in range(5)] for row in range(7)], bool)
          for character, code in zip(_CHARACTERS, _FONT, strict=True)}
"""{character: (7, 5) bool glyph}; other characters draw as a blank."""


def records(history: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The progress records (``training.log.ProgressLog.history``) as ``train --json`` and the
    plot give them: step, the task losses (each positive; the weighted total, which the
    learned weighting drives below zero, is left out) and the validation on the held-out
    poses (None without any)."""
    return [{"step": record["step"], "losses": dict(record["losses"]),
             "validation": None if record.get("validation") is None
             else dict(record["validation"])} for record in history]


def text(image: Float[np.ndarray, "H W 3"], line: str, x: int, y: int,
         color: Sequence[float] = tuple(_INK), align: str = "left") -> None:
    """Draws ``line`` (lower-cased) into ``image`` with its top at row ``y``, starting at
    column ``x`` (``align="right"``: ending there; ``"center"``: centred on it); 6 pixels a
    character. What falls outside the image is left out."""
    line = line.lower()
    width = 6 * len(line) - 1
    x -= {"left": 0, "right": width, "center": width // 2}[align]
    height, image_width = image.shape[:2]
    for index, character in enumerate(line):
        rows, columns = np.nonzero(GLYPHS.get(character, GLYPHS[" "]))
        rows, columns = rows + y, columns + x + 6 * index
        inside = (rows >= 0) & (rows < height) & (columns >= 0) & (columns < image_width)
        image[rows[inside], columns[inside]] = color


def _polyline(image, xs, ys, color, dashed, box):
    """Draws the line through pixel positions (xs, ys), 2 pixels thick, clipped to ``box``
    (left, top, right, bottom); ``dashed``: 6 pixels on, 4 off."""
    left, top, right, bottom = box
    xs, ys = np.asarray(xs, np.float64), np.asarray(ys, np.float64)
    points = [np.stack([xs[:1], ys[:1]], 1)]
    for i in range(len(xs) - 1):
        count = int(math.ceil(max(abs(xs[i + 1] - xs[i]), abs(ys[i + 1] - ys[i])))) + 1
        t = np.linspace(0, 1, count)[1:, None]
        points.append(np.array([xs[i], ys[i]]) * (1 - t) + np.array([xs[i + 1], ys[i + 1]]) * t)
    points = np.concatenate(points)
    if dashed:
        length = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
        points = points[length % 10 < 6]
    for dx in (0, 1):
        for dy in (0, 1):
            x, y = np.round(points[:, 0]).astype(int) + dx, np.round(points[:, 1]).astype(int) + dy
            inside = (x >= left) & (x <= right) & (y >= top) & (y <= bottom)
            image[y[inside], x[inside]] = color


def _step_ticks(last: int) -> list[int]:
    """About five round step numbers (1, 2 or 5 times a power of ten apart, at least 1) from 0
    to ``last``."""
    raw = max(last, 1) / 5
    power = 10 ** math.floor(math.log10(raw))
    spacing = next(m * power for m in (1, 2, 5, 10) if m * power >= raw)
    return list(range(0, last + 1, max(1, round(spacing))))


def plot(history: Sequence[dict[str, Any]]) -> Float[np.ndarray, "H W 3"]:
    """The (H, W, 3) picture (``PLOT_SIZE``, row 0 at the top) of ``records(history)``: each
    task's training loss solid and its loss on the held-out poses dashed, in the task's
    colour, over the steps, on a log scale."""
    width, height = PLOT_SIZE
    image = np.ones((height, width, 3), np.float32)
    text(image, "loss per task: training (solid), held-out poses (dashed)", _LEFT, 8)
    box = (_LEFT, _TOP, width - _RIGHT, height - _BOTTOM)
    left, top, right, bottom = box
    rows = records(history)
    curves = []       # (task, steps, values, dashed)
    tasks = list(rows[0]["losses"]) if rows else []
    for task in tasks:
        curves.append((task, [r["step"] for r in rows], [r["losses"][task] for r in rows],
                       False))
        held_out = [(r["step"], r["validation"][f"loss/{task}"]) for r in rows
                    if r["validation"] and f"loss/{task}" in r["validation"]]
        if held_out:
            curves.append((task, *zip(*held_out), True))
    values = np.array([v for *_, vs, _ in curves for v in vs], np.float64)
    values = values[np.isfinite(values) & (values > 0)]
    if not len(values):
        text(image, "no losses recorded yet", (left + right) // 2, (top + bottom) // 2,
             align="center")
        return image
    low, high = math.floor(math.log10(values.min())), math.ceil(math.log10(values.max()))
    high = max(high, low + 1)
    last = max(r["step"] for r in rows)

    def to_x(step):
        return left + (right - left) * np.asarray(step, np.float64) / max(last, 1)

    def to_y(value):
        logs = np.log10(np.clip(np.asarray(value, np.float64), 10.0 ** low, None))
        return bottom - (bottom - top) * (logs - low) / (high - low)

    for decade in range(low, high + 1):
        y = int(round(float(to_y(10.0 ** decade))))
        image[y, left:right + 1] = _GRID
        text(image, f"1e{decade}", left - 6, y - 3, align="right")
    for step in _step_ticks(last):
        x = int(round(float(to_x(step))))
        image[top:bottom + 1, x] = _GRID
        text(image, f"{step:,}".replace(",", " "), x, bottom + 6, align="center")
    text(image, "step", right, bottom + 18, align="right")
    image[top:bottom + 1, left] = image[bottom, left:right + 1] = _INK
    for task, steps, losses, dashed in curves:
        _polyline(image, to_x(steps), to_y(losses), COLORS.get(task, _INK), dashed, box)
    for index, task in enumerate(tasks):
        y = top + 6 + 16 * index
        _polyline(image, [right + 10, right + 30], [y + 3, y + 3], COLORS.get(task, _INK),
                  False, (0, 0, width - 1, height - 1))
        text(image, task, right + 36, y)
    return image
