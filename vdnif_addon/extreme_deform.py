"""The extreme pose that a ``settings.PoseSpec`` may put on top of every pose (``--deform
KIND:VALUE``): its kinds, their checks and its pose key; ``blender/extremes.py`` applies it.
Like ``settings``, it imports neither bpy nor numpy."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .errors import VDNIFError

DEFORM_KINDS = ("bend", "twist", "stretch", "squash")
"""The extreme poses of ``--deform`` (``blender/extremes.py``)."""


@dataclass(frozen=True)
class ExtremeDeform:
    """An extreme pose: ``amount`` is degrees for bend and twist, a factor for stretch
    (>= 1) and squash (in (0, 1])."""

    kind: str
    amount: float

    def __post_init__(self) -> None:
        if self.kind not in DEFORM_KINDS:
            raise VDNIFError(f"unknown deform kind '{self.kind}': choose one of "
                             f"{', '.join(DEFORM_KINDS)}")
        if not math.isfinite(self.amount):
            raise VDNIFError(f"deform {self.kind} amount {self.amount} is not finite")
        if self.kind == "stretch" and self.amount < 1:
            hint = f" (use squash:{self.amount:g} to shorten)" if self.amount > 0 else ""
            raise VDNIFError(f"stretch factor {self.amount:g} must be at least 1{hint}")
        if self.kind == "squash" and not 0 < self.amount <= 1:
            raise VDNIFError(f"squash factor {self.amount:g} must be in (0, 1]")

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
