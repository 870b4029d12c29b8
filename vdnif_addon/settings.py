"""Every setting's one home: the names a setting may take, its default, its range and its
validation, read by the batch commands' parser, the panel's properties and the core alike
(DESIGN section 8 for the recipe). Holds the configurations of a run: ``NetworkConfig``
(with ``Heads``), ``TrainConfig``; the evaluation pose sets and ``PoseSpec`` are
``pose_sets``'.

Imports neither torch, nor bpy, nor Warp, nor numpy, so the UI and the command-line parser can
read it cheaply. Hard memory caps live in ``limits``; each user setting's default, range and
help is declared once in ``declarations``, and the values here that a user sets are read
from there.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from . import declarations as declared
from . import limits
from .checks import check_choice, check_int, check_number
from .errors import VDNIFError


@dataclass(frozen=True)
class Recipe:
    """Default data and optimization sizes of one training run.

    poses: deformed training poses; rays_per_pose: training rays walked per pose;
    surface_fraction / grazing_fraction / secondary_fraction: shares of those rays aimed from
    outside at a surface point / tangent to the surface at one / starting on the surface, as
    shadow and occlusion rays do (``rays.training_rays``), the rest aimed at random points of
    the bounds; steps and batch_size: optimizer steps of batch_size segments.
    """

    resolution: int = declared.RESOLUTION.default
    # A textured mesh (``RestMesh.albedo_varies``) trains finer: coarser voxels alone move
    # the hits enough to blur the albedo read at them (DESIGN section 8).
    textured_resolution: int = 64
    poses: int = declared.POSES.default
    rays_per_pose: int = declared.RAYS_PER_POSE.default
    surface_fraction: float = declared.SURFACE_FRACTION.default
    grazing_fraction: float = declared.GRAZING_FRACTION.default
    secondary_fraction: float = declared.SECONDARY_FRACTION.default
    steps: int = declared.STEPS.default
    batch_size: int = declared.BATCH_SIZE.default

    def resolution_for(self, textured: bool) -> int:
        """The voxel resolution a mesh trains at unless told: finer where it is textured."""
        return self.textured_resolution if textured else self.resolution


RECIPE = Recipe()
"""The default recipe."""

CALIBRATION_VIEW_SHARE = 1.0
"""The square orbit view walked per pose beside its training rays, as a share of them (256x256
at the recipe's 65,536, the evaluation's size): held out with their pose, its rays calibrate
the occlusion threshold as the render counts holes and extras, per camera ray
(``training.validation.calibrate_threshold``); no training step reads them. The thresholds
miss different rays by well under a percent of a view's rays, so a much smaller view leaves
the choice to chance (``docs/results.md``, *The occlusion threshold on rendered frames*)."""


def calibration_view(rays_per_pose: int) -> int:
    """Pixels on a side of the calibration view of a dataset of ``rays_per_pose``."""
    return int((rays_per_pose * CALIBRATION_VIEW_SHARE) ** 0.5)


OCCLUSION_THRESHOLD = 0.5
"""Occlusion probability above which a segment counts as a hit until training calibrates the
thresholds on held-out poses (``model.metadata.Thresholds``), and the calibration's choice
among equally good ones."""

OCCLUSION_CALIBRATION = "least larger of holes and extras on the held-out poses' views"
"""What training's calibration of the occlusion threshold minimizes
(``training.validation.calibrate_threshold``), as results files record it under their
recipe (``model.provenance``): files that lack it were calibrated on the least sum of the two
(docs/results.md, the first section)."""

DEMO_SCENES, RIGS = ("arm", "lattice", "spot", "bunny"), ("armature", "lattice")
"""Embedded demo scenes; procedural rigs of a scene or a rigless mesh (``blender/scenes.py``)."""
DEMO_SCENE = "spot"
"""The main job's scene (``make demo``): textured and armature-rigged."""

# The suggested resolution (``blender/resolution.py`` says what each value means): the knee
# of the embedding errors within KNEE_MARGIN and KNEE_TOLERANCE of the best candidate's,
# raised for thin parts (THIN_PART_*), held to EMBEDDING_TARGET (object units).
RESOLUTION_CANDIDATES = (8, 12, 16, 24, 32, 48, 64, 96, 128)
KNEE_MARGIN, KNEE_TOLERANCE = 0.5, {"distance": 5e-5, "hit_mismatch": 2e-3}
EMBEDDING_TARGET, THIN_PART_VOXELS, THIN_PART_SHARE = 2e-4, 2.0, 0.01
SUGGEST_POSES, SUGGEST_VIEW_SIZE = 4, 96
# How the corners of an armature or lattice rig follow it (``blender/follow_choice.py``):
# the surface binding replaces the copied modifiers only where its embedding error on the
# suggestion's poses and view is below theirs by FOLLOW_MARGIN (relative) and KNEE_TOLERANCE.
FOLLOW_MARGIN = 0.5

# --------------------------------------------------------------------------- secondary rays
# Ambient occlusion: AO_SAMPLES rays per pixel (standard error at most 0.125, directions from
# SECONDARY_SEED) up to AO_DISTANCE object units (contacts and folds darken, the far side
# does not); shadow rays go to DEFAULT_LIGHT_DIRECTION (object space) where the scene has no
# sun or point light. A secondary ray starts above its hit on the primary ray's side, lest it
# hit the surface it leaves: SECONDARY_OFFSET object units above an exact hit (off by
# rounding only); a network's hit is off by its distance error, so the most of that,
# SECONDARY_OFFSET_VOXELS voxels and SECONDARY_OFFSET_ERRORS x its held-out distance MAE.
AO_SAMPLES, AO_DISTANCE = declared.AO_SAMPLES.default, declared.AO_DISTANCE.default
DEFAULT_LIGHT_DIRECTION, SECONDARY_SEED = (0.3, -0.4, 0.866), 0
SECONDARY_OFFSET, SECONDARY_OFFSET_VOXELS, SECONDARY_OFFSET_ERRORS = 1e-3, 0.125, 1.5
# The height is reached along the ray (a push along the normal shifts a shadow's edge); a ray
# at a cosine below SECONDARY_GRAZING_COSINE goes offset / it along, the rest along the normal.
SECONDARY_GRAZING_COSINE = 0.2
# A network's first hit within SECONDARY_SELF_REACH offsets whose normal is within
# SECONDARY_SELF_COSINE of the left surface's is that surface (its hit lay below it): the ray
# walks on from an offset past it, at most SECONDARY_SELF_SKIPS times.
SECONDARY_SELF_REACH, SECONDARY_SELF_COSINE, SECONDARY_SELF_SKIPS = 4.0, 0.3, 3
# The shaded pass's shadow rates are split at the terminator band |N.L| < TERMINATOR_BAND
# (the reference's normal; 0.175: within 10 degrees of the terminator): there a small normal
# error flips whether the surface faces the light, and the shaded value max(0, N.L) it flips
# is small. Chosen on development poses (docs/results.md, "The shaded image").
TERMINATOR_BAND = 0.175

# --------------------------------------------------------------------------- names

DEVICES, DEFAULT_DEVICE = declared.DEVICE.names, declared.DEVICE.default
"""Where the network runs: auto is CUDA where torch has it, else the CPU."""
PRECISIONS, DEFAULT_PRECISION = declared.PRECISION.names, declared.PRECISION.default
"""The arithmetic of the MLPs in training and in a render (``declarations.PRECISION``)."""
POSE_SOURCES = declared.POSE_SOURCE.names
"""Random bone rotations and lattice offsets, or frames of the scene's frame range."""
DISTANCE_MODES = ("fraction", "log1p-fraction", "log-distance")
"""``fraction``: LSNIF's sigmoid t/l. ``log1p-fraction``: the proposed ReLU log1p(t/l),
scale-invariant, its error taken in t/l (``losses.distance_error``). ``log-distance``: the
paper's written form, ReLU log1p(d/h) of the rest distance d from the segment's start in
voxel edges h, unbounded, its MSE taken in log space (the ablation's; DESIGN section 8)."""
ALBEDO_MODES, NORMAL_MODES = declared.ALBEDO_MODE.names, declared.NORMAL_MODE.names
"""Where the albedo and the normal come from (``declarations.ALBEDO_MODE``)."""
WEIGHTINGS = ("uncertainty", "fixed")
"""Loss weighting (``losses.make_weighting``): learned log-variances, or the plain sum."""
WEIGHTING_STARTS = ("zero", "equal")
"""Where the uncertainty weighting's s_i start: ``zero`` (a classification task weighs 1, a
regression task 0.5), or ``equal``, s_i = log of the task's scale (every task weighs 1)."""
DEFAULT_WEIGHTING_START = "equal"
"""The recipe's start (``TrainConfig.weighting_start`` says why); the paper names none."""
PE_SCALES = dict(zip(declared.PE_FORM.names, (1.0, math.pi), strict=True))
"""``pe_form`` -> frequency scale s in ``sin(2^k s x)``: the paper's form and PEPS's."""
AUTO_RESOLUTION, RECIPE_RESOLUTION = declared.AUTO_RESOLUTION, declared.RECIPE_RESOLUTION
"""``--resolution auto``: the suggested resolution of the scene; ``recipe``: the recipe's."""

# --------------------------------------------------------------------------- ranges

MIN_RESOLUTION, MAX_RESOLUTION = declared.RESOLUTION.range
"""Voxels along the object's longest side."""
MAX_GRID_RESOLUTION = declared.BASE_RESOLUTION.high
"""Cells per axis of the hash grid's finest level."""
MAX_STEPS = declared.STEPS.high
EVALUATION_POSES = declared.EVALUATION_POSES.default
"""Unseen poses a model is evaluated on unless told otherwise (panel and ``evaluate``)."""
COMMAND_IMAGE = (declared.IMAGE_WIDTH.default, declared.IMAGE_HEIGHT.default)
"""Width and height of the batch commands' images (references, render, evaluate)."""
PANEL_IMAGE = tuple(setting.panel[0].default for setting in (declared.IMAGE_WIDTH,
                                                              declared.IMAGE_HEIGHT))
"""Width and height of the panel's renders."""

BOUNDS: dict[str, tuple[float, float]] = declared.bounds()
"""Closed range [low, high] of each numeric setting, by its name (``declarations``)."""

_COUNT = (1, 2**40)
"""Range of the core-only counts (val_segments, log_interval): positive."""
MAX_MATERIALS = 2**15
"""Material slots of a material head (``capture`` stores indices as int16)."""


def level_resolutions(levels: int, base_resolution: int, growth: float) -> list[int]:
    """Cells per axis of each hash-grid level, coarse to fine: ``floor(N_min * b**l)``."""
    return [math.floor(base_resolution * growth**level) for level in range(levels)]


def check_grid_settings(
    levels: int, base_resolution: int, growth: float, log2_table_size: int, feature_dim: int,
    prefix: str = "",
) -> None:
    """Validate hash grid settings with messages that name the setting (a point field's own
    grid: ``prefix`` is its level and table settings' prefix, "normal_" for the normal
    field's, and the messages name that field)."""
    for name, value in (("levels", levels), ("base_resolution", base_resolution),
                        ("log2_table_size", log2_table_size), ("feature_dim", feature_dim)):
        named = prefix + name if name in ("levels", "log2_table_size") else name
        check_int(named, value, *BOUNDS[name])
    check_number("growth", growth, *BOUNDS["growth"])
    grid = f"{prefix.removesuffix('_')} field's hash grid" if prefix else "hash grid"
    resolutions = level_resolutions(levels, base_resolution, growth)
    finest = resolutions[-1]
    if finest > MAX_GRID_RESOLUTION:
        raise VDNIFError(f"{grid} finest resolution {finest} exceeds "
                         f"{MAX_GRID_RESOLUTION} cells per axis")
    floats = feature_dim * sum(min((res + 1) ** 3, 2**log2_table_size) for res in resolutions)
    if floats > limits.MAX_TABLE_FLOATS:
        raise VDNIFError(
            f"{grid} table of {floats} floats is too large: at most {limits.MAX_TABLE_FLOATS}"
            f" (lower {prefix}log2_table_size, {prefix}levels or feature_dim)"
        )


def check_encoding_settings(pe_bands: int, pe_form: str) -> None:
    """Validate positional-encoding settings with messages that name the setting."""
    check_int("pe_bands", pe_bands, *BOUNDS["pe_bands"])
    if pe_form not in PE_SCALES:
        raise VDNIFError(f"setting pe_form must be one of {sorted(PE_SCALES)}, got {pe_form!r}")


# --------------------------------------------------------------------------- network


@dataclass(frozen=True)
class Heads:
    """Which outputs the scene needs (DESIGN.md section 7).

    Occlusion, distance and normal are always present; albedo only when it is not constant
    per material (else a lookup table replaces it); material only when there are several.
    """

    albedo: bool = True
    material_count: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.albedo, bool):
            raise VDNIFError(f"heads setting albedo must be true or false, got {self.albedo!r}")
        check_int("material_count", self.material_count, 1, MAX_MATERIALS)

    @property
    def material(self) -> bool:
        return self.material_count > 1

    def sizes(self) -> dict[str, int]:
        """Head name -> output width, in output-column order."""
        sizes = {"occlusion": 1, "distance": 1, "normal": 3}
        if self.albedo:
            sizes["albedo"] = 3
        if self.material:
            sizes["material"] = self.material_count
        return sizes

    @classmethod
    def from_header(cls, heads: Mapping[str, Any]) -> Heads:
        """From a dataset header's ``heads`` entry:
        {"albedo": bool, "material_count": int, ...}."""
        if not isinstance(heads, Mapping) or not {"albedo", "material_count"} <= set(heads):
            raise VDNIFError(
                f"dataset header 'heads' must give 'albedo' and 'material_count', got {heads!r}"
            )
        return cls(albedo=heads["albedo"], material_count=heads["material_count"])


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture of one intersection network; defaults are the paper's setting. Model
    files store ``to_dict()``: renaming a field breaks every stored model."""

    levels: int = declared.LEVELS.default
    base_resolution: int = declared.BASE_RESOLUTION.default
    growth: float = declared.GROWTH.default
    log2_table_size: int = declared.LOG2_TABLE_SIZE.default
    feature_dim: int = declared.FEATURE_DIM.default
    pe_bands: int = declared.PE_BANDS.default
    pe_form: str = declared.PE_FORM.default
    width: int = declared.WIDTH.default
    depth: int = declared.DEPTH.default
    distance_mode: str = "log1p-fraction"
    albedo_mode: str = declared.ALBEDO_MODE.default
    normal_mode: str = declared.NORMAL_MODE.default
    normal_levels: int = declared.NORMAL_LEVELS.default
    normal_log2_table_size: int = declared.NORMAL_LOG2_TABLE_SIZE.default
    heads: Heads = field(default_factory=Heads)

    def __post_init__(self) -> None:
        check_grid_settings(
            self.levels, self.base_resolution, self.growth, self.log2_table_size, self.feature_dim
        )
        check_grid_settings(self.normal_levels, self.base_resolution, self.growth,
                            self.normal_log2_table_size, self.feature_dim, "normal_")
        check_encoding_settings(self.pe_bands, self.pe_form)
        check_int("width", self.width, *BOUNDS["width"])
        check_int("depth", self.depth, *BOUNDS["depth"])
        check_choice("distance_mode", self.distance_mode, DISTANCE_MODES)
        check_choice("albedo_mode", self.albedo_mode, ALBEDO_MODES)
        check_choice("normal_mode", self.normal_mode, NORMAL_MODES)
        if not isinstance(self.heads, Heads):
            raise VDNIFError(f"setting heads must be a Heads, got {self.heads!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> NetworkConfig:
        """Inverse of ``to_dict``; unknown or malformed entries raise VDNIFError."""
        if not isinstance(data, Mapping):
            raise VDNIFError(f"network config must be a mapping, got {type(data).__name__}")
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise VDNIFError(f"network config has unknown entries {sorted(unknown)}")
        # Files written before the normal field existed have the normal head; those written
        # before it had its own grid read it with the encoder's.
        values = {"normal_mode": "segment", "normal_levels": data.get("levels", cls.levels),
                  "normal_log2_table_size": data.get("log2_table_size", cls.log2_table_size),
                  **data}
        if "heads" in values:
            heads = values["heads"]
            if not isinstance(heads, Mapping) or not set(heads) <= {"albedo", "material_count"}:
                raise VDNIFError(f"network config has malformed heads: {heads!r}")
            values["heads"] = Heads(**heads)
        return cls(**values)


# --------------------------------------------------------------------------- training


@dataclass(frozen=True)
class TrainConfig:
    """Optimization settings; the grid's and the MLP's learning rates follow instant-ngp and
    LSNIF; the loss weighting's log-variances have their own (``lr_weighting``)."""

    steps: int = RECIPE.steps
    batch_size: int = RECIPE.batch_size
    lr_grid: float = 1e-2
    # Not LSNIF's 1e-3, where occlusion idles at the all-miss answer (DESIGN section 8).
    lr_mlp: float = 2e-2
    # The log-variances' own rate stays at the MLP's: faster, they settle, favour the
    # regression tasks over occlusion by the ratio of their losses, and the small scene of
    # tests/posed/test_proposed_beats_deformed.py loses most of its hits (DESIGN section 8).
    lr_weighting: float = 1e-3
    final_lr_fraction: float = 0.1
    # The point fields learn at the reference's hit moved along its ray by N(0, this many
    # voxels): the render reads them at the hit it places, a few hundredths of a voxel off.
    field_jitter: float = 0.05
    weighting: str = "uncertainty"
    # "equal" (every task at weight 1), not "zero" (occlusion at twice a regression task's
    # weight): the log-variances never settle at the recipe, so the start sets the balance of
    # the whole run, and "zero" placed the passes' head-on hits worse than deformed did
    # (DESIGN section 8).
    weighting_start: str = DEFAULT_WEIGHTING_START
    seed: int = declared.SEED.default
    device: str = DEFAULT_DEVICE
    # The MLPs' arithmetic in a step, as a render's (``training.train.Objective``).
    precision: str = DEFAULT_PRECISION
    val_fraction: float = 0.1
    val_segments: int = 2**16
    # Every log_interval steps a validation feeds the stopping rule (``training.stopping``);
    # steps is then a cap, and stop_patience 0 runs them all.
    log_interval: int = 100
    stop_patience: int = 5
    stop_min_gain: float = 0.02

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "seed"):
            check_int(name, getattr(self, name), *BOUNDS[name])
        for name in ("val_segments", "log_interval"):
            check_int(name, getattr(self, name), *_COUNT)
        check_int("stop_patience", self.stop_patience, 0, MAX_STEPS)
        check_number("stop_min_gain", self.stop_min_gain, 0.0, 1.0)
        for name in ("lr_grid", "lr_mlp", "lr_weighting", "final_lr_fraction"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not 0 < value <= 1):
                raise VDNIFError(f"setting {name} must be a number in (0, 1], got {value!r}")
        check_number("val_fraction", self.val_fraction, 0.0, 0.9)
        check_number("field_jitter", self.field_jitter, 0.0, 1.0)
        check_choice("weighting", self.weighting, WEIGHTINGS)
        check_choice("weighting_start", self.weighting_start, WEIGHTING_STARTS)
        check_choice("device", self.device, DEVICES)
        check_choice("precision", self.precision, PRECISIONS)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------- variants

_BASELINE = {"pe_bands": 0, "distance_mode": "fraction", "weighting": "fixed"}
_PROPOSED = {"pe_bands": 3, "distance_mode": "log1p-fraction", "weighting": "uncertainty"}
ABLATIONS = {"proposed-no-pe": "pe_bands", "proposed-no-log": "distance_mode",
             "proposed-no-uncertainty": "weighting"}
"""Each ablation removes one part: the proposed setting of that key goes back to the
baseline's (``variants`` module docstring)."""
VARIANTS: dict[str, dict[str, Any]] = {
    "lsnif": {**_BASELINE, "deformed_data": False},
    "deformed": {**_BASELINE, "deformed_data": True},
    "proposed": {**_PROPOSED, "deformed_data": True},
    **{name: {**_PROPOSED, key: _BASELINE[key], "deformed_data": True}
       for name, key in ABLATIONS.items()},
}
"""Variant name -> its NetworkConfig / TrainConfig fields and whether it trains on many
deformed poses (``deformed_data``) or the rest pose alone."""
TRAINABLE_VARIANTS = declared.TRAINABLE_VARIANTS
"""The methods a user trains (``train --variant``, the panel); the ablations are studies'."""
DEFAULT_VARIANT, STATIC_VARIANT = "proposed", "lsnif"
AUTO_VARIANT = declared.VARIANT.default
"""The panel's choice of DEFAULT_VARIANT or STATIC_VARIANT by the scene (``choose_variant``)."""
