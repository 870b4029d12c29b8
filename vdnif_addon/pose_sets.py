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
serve every choice (recipe, threshold grids, presets, bench points, stopping rules, the
suggested resolution); test poses serve none: the reported tables, the demo's report and
``evaluate`` alone."""
FRAME_OFFSETS = {DEVELOPMENT_POSES: 0.25, TEST_POSES: 0.75}
"""Frames have no seed: evaluation pose set -> where its frames lie in each step after the
range's first frame (``poses.evaluation_frames``). A step is a frame, halved up to
FRAME_HALVINGS times where the range holds too few: a quarter and three quarters of every
halving are different frames (odd multiples of a power of two apart), so the development and
test frames never meet whatever their counts."""
FRAME_HALVINGS = 7
"""Steps of 1/128 frame at the finest: the two sets' frames stay 1/512 frame apart, above
``poses.MIN_FRAME_SPACING``."""


@dataclass(frozen=True)
class PoseSpec:
    """How to choose poses (``blender/poses.py`` draws them): ``count`` random poses from
    ``seed`` or frames of the range; ``deform``: an extreme pose on top of every pose;
    ``pose_set``: None for training poses, else the evaluation set (``POSE_SETS``) they
    belong to; ``avoid`` (``poses.evaluation_spec``): the training poses these must be
    disjoint from, as the PoseSpec that chose them or as a tuple of a model's pose dicts."""

    source: str = declared.POSE_SOURCE.default
    count: int = EVALUATION_POSES
    seed: int = declared.SEED.default
    max_angle_deg: float = declared.MAX_ANGLE.default
    lattice_fraction: float = 0.3
    deform: ExtremeDeform | None = None
    avoid: PoseSpec | tuple[dict[str, Any], ...] | None = None
    pose_set: str | None = None

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
        if self.pose_set is not None and self.pose_set not in POSE_SETS:
            raise VDNIFError(f"unknown pose set '{self.pose_set}': choose one of "
                             f"{', '.join(POSE_SETS)}")
        if self.avoid is not None and self.pose_set is None:
            raise VDNIFError("poses kept apart from training poses are evaluation poses: "
                             "name their pose set")


def pose_key(pose: dict[str, Any]) -> str:
    """A pose as comparable text: equal poses give equal keys, also after a trip through a
    JSON file (dataset header, model file) that turns integer keys into strings."""
    return json.dumps(json.loads(json.dumps(pose)), sort_keys=True)
