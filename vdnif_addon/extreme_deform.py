"""The stress values: the extreme pose that a ``pose_sets.PoseSpec`` may put on top of every
pose (``--deform KIND:VALUE``: its kinds, their checks and its pose key) and the uniform object
scale (``--scale S``); ``blender/extremes.py`` applies them. Like ``settings``, it imports
neither bpy nor numpy, so the command-line parser checks them cheaply."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .errors import VDNIFError

DEFORM_KINDS = ("bend", "twist", "stretch", "squash")
"""The extreme poses of ``--deform`` (``blender/extremes.py``)."""

MAX_TURN_DEG = 3600.0
"""Largest bend or twist, degrees (ten turns). Blender keeps a bone's rotation in float32:
at 3600 degrees it still resolves 0.0002 degrees, at 1e7 degrees about one, and past
about 2e40 it is infinite, so every figure of such a pose is n/a."""
MAX_FACTOR = 100.0
"""Largest stretch and the inverse of the smallest squash: at stretch 1000 the arm (3 units
long, a tenth as thick) lies across 3,000 units and covers no pixel of a 64x64 orbit view, so
every figure is n/a; a hundredfold keeps it in view."""


def parse_scale(text: Any) -> float:
    """A uniform object scale from text: a finite number > 0."""
    try:
        scale = float(text)
    except ValueError:
        raise VDNIFError(f"object scale '{text}' is not a number") from None
    if not (math.isfinite(scale) and scale > 0):
        raise VDNIFError(f"object scale {text} must be a finite number greater than 0")
    return scale


@dataclass(frozen=True)
class ExtremeDeform:
    """An extreme pose: ``amount`` is degrees for bend and twist (within +-MAX_TURN_DEG), a
    factor for stretch (1..MAX_FACTOR) and squash (1/MAX_FACTOR..1)."""

    kind: str
    amount: float

    def __post_init__(self) -> None:
        if self.kind not in DEFORM_KINDS:
            raise VDNIFError(f"unknown deform kind '{self.kind}': choose one of "
                             f"{', '.join(DEFORM_KINDS)}")
        if not math.isfinite(self.amount):
            raise VDNIFError(f"deform {self.kind} amount {self.amount} is not finite")
        if self.kind in ("bend", "twist") and abs(self.amount) > MAX_TURN_DEG:
            raise VDNIFError(f"{self.kind} {self.amount:g} degrees is beyond "
                             f"+-{MAX_TURN_DEG:g} (ten turns)")
        if self.kind == "stretch" and self.amount < 1:
            hint = f" (use squash:{self.amount:g} to shorten)" if self.amount > 0 else ""
            raise VDNIFError(f"stretch factor {self.amount:g} must be at least 1{hint}")
        if self.kind == "stretch" and self.amount > MAX_FACTOR:
            raise VDNIFError(f"stretch factor {self.amount:g} is more than {MAX_FACTOR:g}")
        if self.kind == "squash" and not 0 < self.amount <= 1:
            raise VDNIFError(f"squash factor {self.amount:g} must be in (0, 1]")
        if self.kind == "squash" and self.amount < 1 / MAX_FACTOR:
            raise VDNIFError(f"squash factor {self.amount:g} is less than {1 / MAX_FACTOR:g}")

    @classmethod
    def parse(cls, text: str) -> ExtremeDeform:
        """From ``KIND:VALUE`` text, e.g. ``bend:170`` or ``squash:0.1``."""
        kind, _, value = str(text).partition(":")
        try:
            amount = float(value)
        except ValueError:
            raise VDNIFError(f"deform '{text}' is not KIND:VALUE with a number VALUE "
                             f"(e.g. bend:170, twist:360, stretch:4, squash:0.1)") from None
        return cls(kind.strip().lower(), amount)

    def pose_key(self, obj: Any) -> dict[str, Any]:
        """The JSON-ready ``"deform"`` entry of a pose of mesh object ``obj`` (a bpy Object)."""
        return {"object": obj.name, "kind": self.kind, "amount": self.amount}
