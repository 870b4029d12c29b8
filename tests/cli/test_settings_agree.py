"""One value per setting: the panel's properties (as Blender registered them), the batch
parser's options and the core's configurations agree on every default, range and choice
with ``vdnif_addon/settings.py``.

Each row of a table below names where a setting appears: a property of ``Object.vdnif`` (or
of the preferences), an option of a command, a field of a core configuration. The values
are read from what was built (the registered RNA, read in a fresh Blender process, the
parsed defaults, the dataclass defaults, the validation that refuses a value), never copied
from settings.py.
"""

import dataclasses
import json
import subprocess
import sys
import types

import pytest
from conftest import ENABLE_IN_FRESH_PROCESS, EXTENSION_MODULE

from vdnif_addon import settings
from vdnif_addon.cli import build_parser
from vdnif_addon.cli.options import validate_arguments
from vdnif_addon.errors import VDNIFError
from vdnif_addon.pose_sets import PoseSpec
from vdnif_addon.settings import BOUNDS, RECIPE, NetworkConfig, TrainConfig

NETWORK = NetworkConfig()
TRAIN = TrainConfig()
SPEC = PoseSpec()

# setting: (panel property, command and its option's dest, the core's default or None)
DEFAULTS = {
    # The commands' default is None, the recipe's of the mesh (test_resolution.py).
    "resolution": ("resolution", None, RECIPE.resolution),
    "poses": ("pose_count", ("train", "poses"), RECIPE.poses),
    "evaluation poses": ("eval_poses", ("evaluate", "poses"), settings.EVALUATION_POSES),
    "pose source": ("pose_source", ("train", "pose_source"), SPEC.source),
    "seed": ("seed", ("train", "seed"), SPEC.seed),
    "max angle": ("max_angle", ("train", "max_angle"), SPEC.max_angle_deg),
    "rays per pose": ("rays_per_pose", ("train", "rays_per_pose"), RECIPE.rays_per_pose),
    "steps": ("steps", ("train", "steps"), TRAIN.steps),
    "batch size": ("batch_size", ("train", "batch"), TRAIN.batch_size),
    "levels": ("levels", None, NETWORK.levels),
    "base resolution": ("base_resolution", None, NETWORK.base_resolution),
    "table size": ("log2_table_size", None, NETWORK.log2_table_size),
    "feature dim": ("feature_dim", None, NETWORK.feature_dim),
    "pe bands": ("pe_bands", None, NETWORK.pe_bands),
    "width": ("width", None, NETWORK.width),
    "depth": ("depth", None, NETWORK.depth),
    "surface fraction": (None, ("dataset", "surface_fraction"), RECIPE.surface_fraction),
    "grazing fraction": (None, ("dataset", "grazing_fraction"), RECIPE.grazing_fraction),
    "secondary fraction": (None, ("dataset", "secondary_fraction"),
                           RECIPE.secondary_fraction),
    "ao samples": ("ao_samples", ("evaluate", "ao_samples"), settings.AO_SAMPLES),
    "ao distance": ("ao_distance", ("evaluate", "ao_distance"), settings.AO_DISTANCE),
    "image width": (None, ("evaluate", "width"), settings.COMMAND_IMAGE[0]),
    "image height": (None, ("evaluate", "height"), settings.COMMAND_IMAGE[1]),
}
"""The network options of ``train`` default to None (the variant's own): their default is the
core's, checked through the variant in test_train.test_variants."""

# BOUNDS key: (panel properties, the command and options that take it, core field or None)
RANGES = {
    "resolution": (["resolution"], ("capture", ["--resolution"]), None),
    "poses": (["pose_count", "eval_poses"], ("capture", ["--poses"]), "pose count"),
    "seed": (["seed"], ("capture", ["--seed"]), "train seed"),
    "max_angle": (["max_angle"], ("capture", ["--max-angle"]), "max angle"),
    "rays_per_pose": (["rays_per_pose"], ("dataset", ["--rays-per-pose"]), None),
    "surface_fraction": ([], ("dataset", ["--surface-fraction"]), None),
    "grazing_fraction": ([], ("dataset", ["--grazing-fraction"]), None),
    "secondary_fraction": ([], ("dataset", ["--secondary-fraction"]), None),
    "ao_samples": (["ao_samples"], ("references", ["--ao-samples"]), "secondary"),
    "ao_distance": (["ao_distance"], ("references", ["--ao-distance"]), "secondary"),
    "levels": (["levels"], ("train", ["--levels", "--normal-levels"]), "network"),
    "base_resolution": (["base_resolution"], ("train", ["--base-resolution"]), "network"),
    "growth": ([], ("train", ["--growth"]), "network"),
    "log2_table_size": (["log2_table_size"],
                        ("train", ["--log2-table-size", "--normal-log2-table-size"]), "network"),
    "feature_dim": (["feature_dim"], ("train", ["--feature-dim"]), "network"),
    "pe_bands": (["pe_bands"], ("train", ["--pe-bands"]), "network"),
    "width": (["width"], ("train", ["--width"]), "network"),
    "depth": (["depth"], ("train", ["--depth"]), "network"),
    "steps": (["steps"], ("train", ["--steps"]), "train"),
    "batch_size": (["batch_size"], ("train", ["--batch"]), "train"),
    "image_side": (["image_width", "image_height"],
                   ("references", ["--width", "--height"]), None),
}
"""Every BOUNDS entry appears here (test_every_bound_is_checked)."""


# Run after ENABLE_IN_FRESH_PROCESS: prints the registered properties' defaults, ranges and
# choices as JSON.
DUMP_RNA = f"""
import json

def described(prop):
    found = {{"type": prop.type}}
    if prop.type in ("BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"):
        found["default"] = prop.default
    if prop.type in ("INT", "FLOAT"):
        found["hard_min"], found["hard_max"] = prop.hard_min, prop.hard_max
    if prop.type == "ENUM":
        found["enum_items"] = [item.identifier for item in prop.enum_items]
    return found

def table(rna):
    return {{name: described(prop) for name, prop in rna.properties.items()
             if name != "rna_type" and not getattr(prop, "is_array", False)}}

preferences = bpy.context.preferences.addons["{EXTENSION_MODULE}"].preferences
print(json.dumps([table(bpy.types.Object.bl_rna.properties["vdnif"].fixed_type),
                  table(preferences.bl_rna)]))
"""


@pytest.fixture(scope="module")
def panel():
    """The registered RNA of ``Object.vdnif`` and of the preferences: name -> property (its
    type, default, hard range and enum identifiers), read in a fresh Blender process that
    enables the extension, so this file keeps to one copy of the core in its own process
    (tests/project/test_module_identity.py)."""
    done = subprocess.run([sys.executable, "-c", ENABLE_IN_FRESH_PROCESS + DUMP_RNA],
                          capture_output=True, text=True, timeout=120, check=True)
    tables = json.loads(done.stdout.strip().splitlines()[-1])
    for rows in tables:
        for name, row in rows.items():
            row["enum_items"] = [types.SimpleNamespace(identifier=item)
                                 for item in row.get("enum_items", [])]
            rows[name] = types.SimpleNamespace(**row)
    properties, preferences = tables
    assert len(properties) > 20 and "device" in preferences     # the tables were read
    return properties, preferences


@pytest.fixture(scope="module")
def parser():
    return build_parser()


def command_defaults(parser, command):
    """The parsed defaults of ``command`` with the fewest arguments it takes."""
    required = {"dataset": ["--out", "d"], "evaluate": ["--model", "m"], "train": [],
                "references": [], "capture": []}[command]
    return parser.parse_args([command, *required])


def refused(parser, command, option, value):
    """Whether ``command option value`` fails its validation (or its parsing)."""
    required = {"dataset": ["--out", "d"], "train": ["--data", "d"]}.get(command, [])
    try:
        validate_arguments(parser.parse_args([command, *required, f"{option}={value}"]))
    except VDNIFError:
        return True
    return False


def core_refuses(kind, name, value):
    """Whether the core configuration ``kind`` refuses ``value`` for the field ``name``."""
    try:
        if kind == "network":
            # One level for the largest base resolution, no growth for the most levels: else
            # the finest level passes its own cap first.
            alone = {"base_resolution": {"levels": 1, "normal_levels": 1},
                     "levels": {"growth": 1.0}}
            NetworkConfig(**{name: value, **alone.get(name, {})})
        elif kind == "train":
            TrainConfig(**{name: value})
        elif kind == "train seed":
            TrainConfig(seed=value)
        elif kind == "pose count":
            PoseSpec(count=value)
        elif kind == "max angle":
            PoseSpec(max_angle_deg=value)
        elif kind == "secondary":
            from vdnif_addon.inference.secondary import SecondarySettings
            SecondarySettings(**{name.removeprefix("ao_"): value})
    except VDNIFError:
        return True
    return False


def step_of(low, high):
    """A small step past a bound: 1 for integers, a millionth of the range else."""
    return 1 if isinstance(low, int) and isinstance(high, int) else (high - low) * 1e-6


@pytest.mark.parametrize("name", list(DEFAULTS))
def test_defaults_agree(name, panel, parser):
    prop, option, core = DEFAULTS[name]
    values = {"core": core}
    if prop is not None:
        values["panel"] = panel[0][prop].default
    if option is not None:
        command, dest = option
        values["command"] = getattr(command_defaults(parser, command), dest)
    assert len(values) > 1, f"{name} appears in one place only: not a row of this table"
    assert all(value == pytest.approx(core) if isinstance(core, float) else value == core
               for value in values.values()), values


@pytest.mark.parametrize("name", list(RANGES))
def test_ranges_agree(name, panel, parser):
    low, high = BOUNDS[name]
    props, (command, options), core = RANGES[name]
    for prop in props:
        rna = panel[0][prop]
        assert (rna.hard_min, rna.hard_max) == pytest.approx((low, high)), prop
    step = step_of(low, high)
    for option in options:
        assert not refused(parser, command, option, low) and not refused(
            parser, command, option, high), (option, low, high)
        assert refused(parser, command, option, low - step), (option, low - step)
        assert refused(parser, command, option, high + step), (option, high + step)
    if core is not None:
        field = {"pose count": "count", "max angle": "max_angle_deg",
                 "train seed": "seed"}.get(core, name)
        assert not core_refuses(core, field, low) and not core_refuses(core, field, high)
        assert core_refuses(core, field, low - step) and core_refuses(core, field, high + step)


def test_every_bound_is_checked():
    assert set(RANGES) == set(BOUNDS)


def test_choices_agree(panel, parser):
    properties, preferences = panel

    def items(rna):
        return [item.identifier for item in rna.enum_items]

    def choices(command, dest):
        subparsers = next(action for action in parser._actions if action.dest == "command")
        action = next(action for action in subparsers.choices[command]._actions
                      if action.dest == dest)
        return list(action.choices)

    assert items(preferences["device"]) == list(settings.DEVICES)
    assert preferences["device"].default == settings.DEFAULT_DEVICE == TRAIN.device
    assert items(properties["device"]) == ["PREFERENCES", *settings.DEVICES]
    for command in ("train", "evaluate", "render", "demo", "bench-network"):
        assert choices(command, "device") == list(settings.DEVICES), command
        assert command_defaults_device(parser, command) == settings.DEFAULT_DEVICE
    assert items(properties["precision"]) == list(settings.PRECISIONS)
    assert properties["precision"].default == settings.DEFAULT_PRECISION
    for command in ("render", "evaluate", "side-by-side"):
        assert choices(command, "precision") == list(settings.PRECISIONS), command
    assert items(properties["pose_source"]) == choices("capture", "pose_source") == list(
        settings.POSE_SOURCES)
    assert sorted(items(properties["variant"])) == sorted(
        [settings.AUTO_VARIANT, *choices("train", "variant")])
    assert choices("train", "variant") == list(settings.TRAINABLE_VARIANTS)
    assert set(settings.TRAINABLE_VARIANTS) <= set(settings.VARIANTS)


def command_defaults_device(parser, command):
    required = {"evaluate": ["--model", "m"], "render": ["--model", "m", "--out", "o"]}
    return parser.parse_args([command, *required.get(command, [])]).device


def test_the_core_refuses_what_settings_does_not_name():
    """Core choices come from settings: a name outside them is refused, each inside taken."""
    from vdnif_addon.training.losses import make_weighting

    for name in settings.WEIGHTINGS:
        assert TrainConfig(weighting=name).weighting == name
        learns = bool(list(make_weighting(name, ("occlusion", "distance")).parameters()))
        assert learns == (name == "uncertainty")           # the core builds each by its name
    for name in settings.DEVICES:
        assert TrainConfig(device=name).device == name
    for name in settings.DISTANCE_MODES:
        assert NetworkConfig(distance_mode=name).distance_mode == name
    for name in settings.PE_SCALES:
        assert NetworkConfig(pe_form=name).pe_form == name
    for name in settings.ALBEDO_MODES:
        assert NetworkConfig(albedo_mode=name).albedo_mode == name
    for name in settings.NORMAL_MODES:
        assert NetworkConfig(normal_mode=name).normal_mode == name
    for field, value in (("device", "tpu"), ("weighting", "equal")):
        with pytest.raises(VDNIFError, match=field):
            TrainConfig(**{field: value})
    for field, value in (("distance_mode", "linear"), ("pe_form", "cosine"),
                         ("albedo_mode", "texture"), ("normal_mode", "vertex")):
        with pytest.raises(VDNIFError, match=field):
            NetworkConfig(**{field: value})
    with pytest.raises(VDNIFError, match="pose source"):
        PoseSpec(source="timeline")
    assert [field.name for field in dataclasses.fields(NetworkConfig)] == [
        "levels", "base_resolution", "growth", "log2_table_size", "feature_dim", "pe_bands",
        "pe_form", "width", "depth", "distance_mode", "albedo_mode", "normal_mode",
        "normal_levels", "normal_log2_table_size", "heads"]  # model files' keys
