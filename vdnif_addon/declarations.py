"""Each user setting declared once: its name, type, range, default and one-line help, and how it
appears as a batch command's option and as a property of the panel. The command-line options
(``cli.options.add_setting``), the panel's properties (``properties.py``), the option tables
of ``docs/cli.md`` (``tools/cli_docs.py``) and the core's ranges (``settings.BOUNDS``, the
configurations' defaults) are generated from or read from these records, in the way
nerfstudio and tyro derive a command line from typed configurations.

A new setting is one ``Setting`` here (and the core field that consumes it); see the
recipe in docs/DESIGN.md section 8.

Imports neither argparse, bpy, torch nor numpy: the core's foundation reads it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from . import limits

SAME = "<the setting's default>"
"""An option's or property's default that is the setting's own."""


@dataclass(frozen=True)
class Choice:
    """One value of a choice setting: its name (the option's word and the enum identifier),
    the panel's label and tooltip, and the number a .blend stores it by (None: its place)."""

    name: str
    label: str = ""
    description: str = ""
    number: int | None = None


@dataclass(frozen=True)
class Option:
    """How a setting appears on the command line: its flag, the commands that take it, the
    metavar, the option's own help where the setting's reads wrong there, its default (SAME,
    or None where the command computes it later and its help says how) and the commands
    whose default differs (``per_command``: (command, default) pairs), and the choices it
    takes where they are fewer than the panel's (``choices``). A choice option whose
    ``parse_choices`` is false takes any word and is refused by the validation with the
    choices named (the network options, all None until the variant fills them). ``label``
    names the option in range errors (the flag unless given); ``group`` the set of options it
    belongs to where the command adds them together (``NETWORK_GROUP``); ``words`` the values
    a number option takes besides a number, each resolved by the command."""

    flag: str
    commands: tuple[str, ...]
    metavar: str | None = None
    help: str | None = None
    default: Any = SAME
    per_command: tuple[tuple[str, Any], ...] = ()
    parse_choices: bool = True
    label: str | None = None
    choices: tuple[str, ...] | None = None
    group: str = ""
    words: tuple[str, ...] = ()

    def names(self, setting: Setting) -> tuple[str, ...]:
        """The words the option takes: its own ``choices``, else the setting's."""
        return self.choices if self.choices is not None else setting.names

    @property
    def dest(self) -> str:
        return self.flag.removeprefix("--").replace("-", "_")

    def default_for(self, setting: Setting, command: str) -> Any:
        value = dict(self.per_command).get(command, self.default)
        return setting.default if value is SAME else value


@dataclass(frozen=True)
class Panel:
    """A property of the panel's ``Object.vdnif`` that holds the setting: its RNA name (a
    .blend stores the value under it: never rename one), label, tooltip, default (SAME or
    its own), soft limits, subtype and shown decimals, enum items placed before the
    setting's choices (``extra``), and the sidebar panel class that draws it after its own
    layout (``section``; empty where that layout places it itself)."""

    rna: str
    label: str
    description: str
    default: Any = SAME
    soft_min: float | None = None
    soft_max: float | None = None
    subtype: str | None = None
    precision: int | None = None
    extra: tuple[Choice, ...] = ()
    section: str = ""

    def default_of(self, setting: Setting) -> Any:
        return setting.default if self.default is SAME else self.default


@dataclass(frozen=True)
class Setting:
    """One user setting: ``name`` is its core field, ``kind`` int, float, str (a choice) or
    bool; ``low``..``high`` the closed range of a number (the one range the parser, the
    panel and the core check)."""

    name: str
    kind: type
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    choices: tuple[Choice, ...] = ()
    option: Option | None = None
    panel: tuple[Panel, ...] = ()

    @property
    def range(self) -> tuple[Any, Any]:
        return self.low, self.high

    @property
    def names(self) -> tuple[str, ...]:
        """The choices' names, in order."""
        return tuple(choice.name for choice in self.choices)

    def enum_items(self, extra: tuple[Choice, ...] = ()) -> list[tuple[Any, ...]]:
        """Blender enum items (identifier, label, description[, number]) of the choices."""
        return [(c.name, c.label, c.description) + (() if c.number is None else (c.number,))
                for c in (*extra, *self.choices)]


SCENE_COMMANDS = ("capture", "dataset", "references", "train")
MODEL_COMMANDS = ("render", "evaluate")
POSE_COMMANDS = (*SCENE_COMMANDS, *MODEL_COMMANDS)
"""Commands that read a scene and pose it (``cli.options.add_pose_options``)."""
NETWORK_COMMANDS = ("train", "evaluate", "render", "demo", "experiment", "bench",
                    "side-by-side", "bench-network")
"""Commands that run a network (``--device``)."""
IMAGE_COMMANDS = ("references", "render", "evaluate", "side-by-side")
"""Commands whose --width/--height are an image's (train's --width is the MLP's)."""
NETWORK_GROUP = "encoding and network (default: the variant's)"
"""``train``'s options of the network, each None (the variant's own) unless given."""

# --------------------------------------------------------------------------- voxels, poses

_POSE_COUNT = (1, limits.MAX_POSES)
"""Poses of one capture (``limits``); evaluation poses too."""
EVALUATION_POSES = Setting(
    "evaluation_poses", int, 8, "unseen poses a model is evaluated on", *_POSE_COUNT,
    panel=(Panel("eval_poses", "Evaluation Poses", "Unseen poses the model is evaluated on"),))
AUTO_RESOLUTION = "auto"
"""``--resolution auto``: the resolution suggested for the scene (``blender/resolution.py``),
the default of the commands that read a scene. The setting's own default is the recipe's
fixed resolution: the panel's field, and what the paper's experiments train at."""
RECIPE_RESOLUTION = "recipe"
"""``--resolution recipe``: the recipe's fixed resolution for the mesh (``Recipe.resolution_for``),
as the paper's experiments train."""
RESOLUTION = Setting(
    "resolution", int, 32, "voxels along the longest side", 4, 256,
    option=Option("--resolution", (*POSE_COMMANDS, "side-by-side"), "R", default=None,
                  per_command=tuple((command, AUTO_RESOLUTION) for command in SCENE_COMMANDS),
                  words=(AUTO_RESOLUTION, RECIPE_RESOLUTION)),
    panel=(Panel("resolution", "Voxel Resolution", "Voxels along the object's longest side: "
                 "more follow finer detail and bends, and make the dataset larger"),))
POSES = Setting(
    "poses", int, 32, "number of poses", *_POSE_COUNT,
    option=Option("--poses", (*POSE_COMMANDS, "side-by-side"), "N", per_command=(
        ("capture", 8), ("references", 4), ("render", 1),
        ("evaluate", EVALUATION_POSES.default), ("side-by-side", 4))),
    panel=(Panel("pose_count", "Pose Count", "Poses the network learns from: more poses "
                 "cover more of the rig's motion; each adds to the dataset and its time",
                 soft_max=1024),))
POSE_SOURCE = Setting(
    "pose_source", str, "random", "random bone rotations / lattice offsets, or timeline frames",
    choices=(Choice("random", "Random", "Random bone rotations and lattice offsets"),
             Choice("frames", "Frame Range", "Frames spread over the scene's frame range")),
    option=Option("--pose-source", POSE_COMMANDS),
    panel=(Panel("pose_source", "Poses", "Where the poses the network learns from come "
                 "from"),))
SEED = Setting(
    "seed", int, 0, "random pose seed", 0, limits.MAX_SEED,
    option=Option("--seed", (*POSE_COMMANDS, "side-by-side"), "S"),
    panel=(Panel("seed", "Seed", "Starting number of the random poses and of training's "
                 "random choices: another seed gives other poses"),))
MAX_ANGLE = Setting(
    # 0.1: the panel's smallest; a rotation of 0 or less makes no random pose.
    "max_angle", float, 45.0, "largest random bone rotation per axis where the bone has no "
    "rotation limits", 0.1, 180.0,
    option=Option("--max-angle", POSE_COMMANDS, "DEG"),
    panel=(Panel("max_angle", "Maximum Angle", "Largest random bone rotation per axis in "
                 "degrees, for bones without rotation limits"),))

# --------------------------------------------------------------------------- training rays

RAYS_PER_POSE = Setting(
    # Many distinct ray lines near silhouettes remove holes and extras (docs/HOLES.md); more
    # than this cost memory for little gain (docs/DESIGN.md section 8, training rays per pose).
    "rays_per_pose", int, 65536, "training rays per pose", 1, limits.MAX_RAYS_PER_POSE,
    option=Option("--rays-per-pose", ("dataset", "train"), "K", label="rays per pose"),
    panel=(Panel("rays_per_pose", "Rays per Pose", "Rays shot at the object in each pose to "
                 "make training examples: more rays, fewer holes, a larger dataset",
                 soft_max=65536),))
SURFACE_FRACTION = Setting(
    "surface_fraction", float, 0.4, "share of rays aimed from outside at a surface point",
    0.0, 1.0, option=Option("--surface-fraction", ("dataset",), "F"))
GRAZING_FRACTION = Setting(
    "grazing_fraction", float, 0.3, "share of rays tangent to the surface at a surface point "
    "(silhouette rays); the rest aim at random points in the bounds", 0.0, 1.0,
    option=Option("--grazing-fraction", ("dataset",), "F"))
SECONDARY_FRACTION = Setting(
    # None: on the development poses no share above 0 gave a better shaded image, and every
    # one cost primary distance (results.md, "Secondary rays").
    "secondary_fraction", float, 0.0, "share of rays that start on the surface and leave it, "
    "as shadow and occlusion rays do", 0.0, 1.0,
    option=Option("--secondary-fraction", ("dataset",), "F"))

# --------------------------------------------------------------------------- secondary rays

AO_SAMPLES = Setting(
    "ao_samples", int, 16, "ambient-occlusion rays per pixel", 1, 1024,
    option=Option("--ao-samples", IMAGE_COMMANDS, "N"),
    panel=(Panel("ao_samples", "AO Samples", "Ambient-occlusion rays per pixel: more give a "
                 "smoother image and take longer", soft_max=256),))
AO_DISTANCE = Setting(
    "ao_distance", float, 0.1, "how far an ambient-occlusion ray looks, in object units",
    1e-6, 1e3,
    option=Option("--ao-distance", IMAGE_COMMANDS, "D"),
    panel=(Panel("ao_distance", "AO Distance", "How far an ambient-occlusion ray looks for an "
                 "occluder, in object units (the object's longest side is 1)", soft_max=1.0,
                 precision=3),))

# --------------------------------------------------------------------------- network
# The paper's setting, except where a comment says why not. Model files store the
# configuration by these names: renaming one breaks every stored model.


def _network(flag: str, metavar: str, **options: Any) -> Option:
    """A ``train`` option of the encoding and network, None unless given: the variant's."""
    return Option(flag, ("train",), metavar, default=None, group=NETWORK_GROUP, **options)


LEVELS = Setting(
    "levels", int, 2, "hash-grid levels L", 1, 64, option=_network("--levels", "L"),
    panel=(Panel("levels", "Levels", "Detail levels of the hash grid, coarse to fine: more "
                 "levels hold finer detail and render a little slower", soft_max=16),))
BASE_RESOLUTION = Setting(
    # Its cap is the finest level's too (settings.MAX_GRID_RESOLUTION).
    "base_resolution", int, 64, "coarsest hash-grid resolution N_min", 1, 2**16,
    option=_network("--base-resolution", "N"),
    panel=(Panel("base_resolution", "Base Resolution", "Cells along each side of the coarsest "
                 "hash-grid level"),))
GROWTH = Setting(
    "growth", float, 2.0, "resolution growth factor b between levels", 1.0, 16.0,
    option=_network("--growth", "B"))
LOG2_TABLE_SIZE = Setting(
    "log2_table_size", int, 16, "hash table size 2^T per level, at most (smaller where the "
    "scene's voxels read fewer)", 1, limits.MAX_LOG2_TABLE_SIZE,
    option=_network("--log2-table-size", "T"),
    panel=(Panel("log2_table_size", "Table Size (log2)", "Entries of each hash-grid level as a "
                 "power of two (16: 65,536), at most: larger tables keep more detail in a "
                 "larger model; a small or thin object's table holds only what it reads"),))
FEATURE_DIM = Setting(
    "feature_dim", int, 3, "features per hash-grid entry Fd", 1, 64,
    option=_network("--feature-dim", "F"),
    panel=(Panel("feature_dim", "Feature Dim", "Numbers stored per hash-grid entry: more hold "
                 "more detail in a larger, slower model"),))
PE_BANDS = Setting(
    "pe_bands", int, 3, "positional-encoding bands F (0: plain LSNIF grid)", 0, 16,
    option=_network("--pe-bands", "F"),
    panel=(Panel("pe_bands", "PE Bands", "Positional-encoding bands: waves of rising "
                 "frequency that let the network place fine detail (0: none; Automatic "
                 "uses its variant's own)"),))
PE_FORM = Setting(
    # The frequency scale s in sin(2^k s x) of each form is settings.PE_SCALES'.
    "pe_form", str, "paper", "sin(2^k x) ('paper') or sin(pi 2^k x) ('pi')",
    choices=(Choice("paper"), Choice("pi")),
    option=_network("--pe-form", "paper|pi", parse_choices=False))
WIDTH = Setting(
    "width", int, 64, "MLP width", 1, 4096, option=_network("--width", "W"),
    panel=(Panel("width", "Width", "Neurons per layer of the network: wider learns more and "
                 "renders slower"),))
DEPTH = Setting(
    "depth", int, 3, "MLP hidden layers", 1, 64, option=_network("--depth", "D"),
    panel=(Panel("depth", "Depth", "Hidden layers of the network: deeper learns more and "
                 "renders slower"),))
_AT_HIT = "from the MLP over the segment ('segment') or from a field of the rest point read " \
          "at the placed hit ('hit')"
ALBEDO_MODE = Setting(
    # The field at the placed hit: a sharper albedo, and the MLP freed of the albedo columns
    # places hits better. segment: the paper's albedo head over the segment's end points;
    # hit: an albedo field of the rest point (``IntersectionNetwork.point_fields``; DESIGN 8).
    "albedo_mode", str, "hit", f"albedo {_AT_HIT}",
    choices=(Choice("segment"), Choice("hit")),
    option=_network("--albedo-mode", "hit|segment", parse_choices=False))
NORMAL_MODE = Setting(
    # The same for the normal: it follows the placed hit, and the shadow's facing test with it.
    "normal_mode", str, "hit", f"normal {_AT_HIT}",
    choices=(Choice("segment"), Choice("hit")),
    option=_network("--normal-mode", "hit|segment", parse_choices=False))
NORMAL_LEVELS = Setting(
    # The normal field's own grid (the base resolution, growth and features of the one above),
    # finer than the encoder's: a scanned surface's normal varies within a voxel, and the
    # shadow's facing test reads it at the terminator.
    "normal_levels", int, 3, "the normal field's hash-grid levels", LEVELS.low, LEVELS.high,
    option=_network("--normal-levels", "L"))
NORMAL_LOG2_TABLE_SIZE = Setting(
    "normal_log2_table_size", int, 17, "the normal field's hash table size 2^T per level, at "
    "most",
    LOG2_TABLE_SIZE.low, LOG2_TABLE_SIZE.high, option=_network("--normal-log2-table-size", "T"))

# --------------------------------------------------------------------------- optimization

STEPS = Setting(
    # A cap the stopping rule may end sooner; clean passes need 3,000 (DESIGN section 8). The
    # panel's IntProperty holds a signed 32-bit int; 10^7 is far beyond any useful run.
    "steps", int, 3000, "optimizer steps at most; training stops sooner once the held-out poses "
    "stop improving", 1, 10**7,
    option=Option("--steps", ("train", "demo"), "N", per_command=(("demo", None),)),
    panel=(Panel("steps", "Steps", "Training steps: more steps take longer and usually lower "
                 "the error"),))
BATCH_SIZE = Setting(
    "batch_size", int, 2**14, "segments per step and process", 1, limits.MAX_BATCH,
    option=Option("--batch", ("train",), "B"),
    panel=(Panel("batch_size", "Batch Size", "Ray pieces the network learns from per step: "
                 "larger batches learn steadier and need more memory"),))
GROUP_TIMEOUT = Setting(
    "group_timeout_s", float, limits.GROUP_TIMEOUT_S, "under torchrun, seconds a process "
    "waits for the others before it stops with an error", 1.0, limits.MAX_GROUP_TIMEOUT_S,
    option=Option("--group-timeout", ("train",), "S"))
TRAINABLE_VARIANTS = ("lsnif", "deformed", "proposed")
"""The methods a user trains (``train --variant``, the panel); the ablations are studies'."""
VARIANT = Setting(
    # Numbered: a .blend stores an enum by number, and "auto" came after the other three.
    "variant", str, "auto", "the network variant",
    choices=(Choice("auto", "Automatic", "LSNIF where no armature or lattice deforms the "
                    "object (a static scene), else Proposed; each with its own PE bands", 3),
             Choice("proposed", "Proposed", "VDNIF: positional bands, log-space distance, "
                    "uncertainty weighting, trained on many poses", 0),
             Choice("deformed", "Deformed", "The LSNIF model trained on many poses", 1),
             Choice("lsnif", "LSNIF", "The static baseline: hash grid only, trained on the "
                    "rest pose", 2)),
    option=Option("--variant", ("train",), default=None, choices=TRAINABLE_VARIANTS,
                  help="the network variant (default: lsnif for a static scene, one that no "
                       "armature or lattice deforms, else proposed)"),
    panel=(Panel("variant", "Variant", "Which kind of network to train"),))

# --------------------------------------------------------------------------- running

DEVICE = Setting(
    "device", str, "auto", "where the network runs",
    choices=(Choice("auto", "Auto", "CUDA when available, else the CPU"),
             Choice("cpu", "CPU", "Train and render on the CPU"),
             Choice("cuda", "CUDA", "Train and render on the first CUDA GPU")),
    option=Option("--device", NETWORK_COMMANDS, per_command=(("side-by-side", "cpu"),)),
    panel=(Panel("device", "Device", "Where training and rendering run: the CPU or an NVIDIA "
                 "GPU", default="PREFERENCES", extra=(
                     Choice("PREFERENCES", "Preferences",
                            "The device chosen in the add-on's preferences"),)),))
PRECISION = Setting(
    # The hash grids and the readout stay float32 either way. A .blend stores the choice by
    # its number: float32 and bfloat16 keep theirs from before auto.
    "precision", str, "auto", "the network MLPs' arithmetic in training and rendering: auto "
    "takes bfloat16 where the device has it (CUDA, a CPU with AVX-512 BF16 or AMX), float32 "
    "elsewhere",
    choices=(Choice("auto", "Auto", "BFloat16 where the device has bfloat16 instructions, "
                    "Float32 elsewhere", number=2),
             Choice("float32", "Float32", "Full precision", number=0),
             Choice("bfloat16", "BFloat16", "Faster where the device has bfloat16 instructions "
                    "(an NVIDIA GPU, a CPU with AVX-512 BF16 or AMX), a little less exact; "
                    "refused elsewhere", number=1)),
    option=Option("--precision", ("train", *MODEL_COMMANDS, "side-by-side", "bench-network")),
    panel=(Panel("precision", "Precision", "The arithmetic of the network's layers when it "
                 "trains and renders"),))
IMAGE_WIDTH = Setting(
    "image_width", int, 128, "image width in pixels", 1, limits.MAX_IMAGE_SIDE,
    option=Option("--width", IMAGE_COMMANDS, "W", label="image width",
                                 per_command=(("side-by-side", 256),)),
    # The panel's renders: a 4:3 picture worth looking at.
    panel=(Panel("image_width", "Width", "Width of the rendered pass images in pixels",
                 default=320, subtype="PIXEL"),))
IMAGE_HEIGHT = Setting(
    "image_height", int, 128, "image height in pixels", 1, limits.MAX_IMAGE_SIDE,
    option=Option("--height", IMAGE_COMMANDS, "H", label="image height",
                                 per_command=(("side-by-side", 256),)),
    panel=(Panel("image_height", "Height", "Height of the rendered pass images in pixels",
                 default=240, subtype="PIXEL"),))

SETTINGS: tuple[Setting, ...] = tuple(
    value for value in dict(globals()).values() if isinstance(value, Setting))
"""Every declared setting, in declaration order."""
BY_NAME = {setting.name: setting for setting in SETTINGS}


def bounds() -> dict[str, tuple[Any, Any]]:
    """The closed range [low, high] of each numeric setting, by its name."""
    return {s.name: s.range for s in SETTINGS if s.kind in (int, float)}


def panel_properties() -> dict[str, tuple[Setting, Panel]]:
    """RNA name -> (setting, panel property) of every declared panel property."""
    return {panel.rna: (setting, panel) for setting in SETTINGS for panel in setting.panel}


def command_options(command: str, group: str | None = None) -> list[Setting]:
    """The declared settings that ``command`` takes as options (those of ``group`` alone,
    given one), in declaration order."""
    return [s for s in SETTINGS if s.option is not None and command in s.option.commands
            and group in (None, s.option.group)]
