"""The default training recipe: the one place that holds how much data and training a model
gets unless the user says otherwise (DESIGN section 8). The batch commands, the demo, the
panel's defaults, ``TrainConfig`` and the presets read it.

Imports neither torch nor bpy, so the UI and the command-line parser can read it cheaply.
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class Recipe:
    """Default data and optimization sizes of one training run.

    poses: deformed training poses; rays_per_pose: training rays walked per pose;
    surface_fraction / grazing_fraction: shares of those rays aimed from outside at a surface
    point / tangent to the surface at one (``rays.training_rays``), the rest aimed at random
    points of the bounds; steps and batch_size: optimizer steps of batch_size segments.
    """

    resolution: int = 32
    poses: int = 32
    rays_per_pose: int = 16384
    surface_fraction: float = 0.4
    grazing_fraction: float = 0.3
    steps: int = 3000
    batch_size: int = 2**14


RECIPE = Recipe()
"""The default recipe."""

OCCLUSION_THRESHOLD = 0.5
"""Occlusion probability above which a segment counts as a hit, for a model file that holds
no threshold calibrated on held-out poses (files written before calibration existed)."""

DEMO_SCENE = "spot"
"""The main job's scene (``make demo``): textured and armature-rigged."""

# The suggested resolution (``blender/resolution.py``): the coarsest candidate whose
# embedding error (true vs embedded reference, distance MAE in object units) is at most
# EMBEDDING_ERROR_SHARE of the network error that preset SUGGEST_PRESET measured, on
# SUGGEST_POSES poses at SUGGEST_VIEW_SIZE^2 pixels.
RESOLUTION_CANDIDATES = (8, 12, 16, 24, 32, 48, 64, 96, 128)
EMBEDDING_ERROR_SHARE = 0.1
SUGGEST_PRESET = "balanced"
SUGGEST_POSES = 4
SUGGEST_VIEW_SIZE = 96
