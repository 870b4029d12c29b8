"""How poses are chosen: the development and test pose sets, and ``PoseSpec`` (its extreme
pose: ``extreme_deform``'s). A settings module like ``settings``, read by the parser, the
panel and the core; it imports neither torch, nor bpy, nor Warp, nor numpy."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from . import declarations as declared
from .errors import VDNIFError
from .settings import BOUNDS, EVALUATION_POSES, POSE_SOURCES

if TYPE_CHECKING:
    from .extreme_deform import ExtremeDeform

DEVELOPMENT_POSES, TEST_POSES = "development", "test"
POSE_SETS = {DEVELOPMENT_POSES: 1_000_003, TEST_POSES: 2_000_029}
"""Evaluation pose set -> its random seed's offset from the training seed. Development poses
serve every choice (recipe, threshold grids, presets, bench points, stopping rules); test
poses serve none: the reported tables, the demo's report and ``evaluate`` alone."""


@dataclass(frozen=True)
class PoseSpec:
    """How to choose poses (``blender/poses.py`` draws them): ``count`` random poses from
    ``seed`` or frames of the range; ``deform``: an extreme pose on top of every pose;
    ``avoid`` (``poses.evaluation_spec``): the training poses these must be disjoint from, as
    the PoseSpec that chose them or as a tuple of a model's pose dicts."""

    source: str = declared.POSE_SOURCE.default
    count: int = EVALUATION_POSES
    seed: int = declared.SEED.default
    max_angle_deg: float = declared.MAX_ANGLE.default
    lattice_fraction: float = 0.3
    deform: ExtremeDeform | None = None
    avoid: PoseSpec | tuple[dict[str, Any], ...] | None = None

    def __post_init__(self) -> None:
        if self.source not in POSE_SOURCES:
            raise VDNIFError(f"unknown pose source '{self.source}': "
                             f"choose one of {', '.join(POSE_SOURCES)}")
        low, high = BOUNDS["poses"]
        if not low <= self.count <= high:
            raise VDNIFError(f"pose count {self.count} is outside {low}..{high}")
        low, high = BOUNDS["max_angle"]
        if not low <= self.max_angle_deg <= high:
            raise VDNIFError(f"maximum angle {self.max_angle_deg} degrees is outside "
                             f"{low:g}..{high:g}")
        if not 0 < self.lattice_fraction <= 1:
            raise VDNIFError(f"lattice offset fraction {self.lattice_fraction} is outside (0, 1]")


def pose_key(pose: dict[str, Any]) -> str:
    """A pose as comparable text: equal poses give equal keys, also after a trip through a
    JSON file (dataset header, model file) that turns integer keys into strings."""
    return json.dumps(json.loads(json.dumps(pose)), sort_keys=True)
