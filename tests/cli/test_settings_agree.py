"""The generators make what the settings' declarations say (``vdnif_addon/declarations.py``):
every declared option is in the commands that take it with the declared flag, metavar,
default, choices and help (``cli.options.add_setting``); every declared panel property is
registered under its RNA name with the declared type, default, range and items
(``properties.declared_property``, read in a fresh Blender process); docs/cli.md's option
tables are what ``tools/cli_docs.py`` writes; the core's configurations default to the
declared values; and the parser, the panel and the core each refuse a value just past the
declared range and take its bounds.

Values are read from what was built (the parser's actions, the registered RNA, the
configurations, the validation that refuses a value), never copied from the declarations.
"""

import argparse
import dataclasses
import importlib.util
import inspect
import json
import subprocess
import sys
import types

import numpy as np
import pytest
from conftest import ENABLE_IN_FRESH_PROCESS, EXTENSION_MODULE, REPO

from vdnif_addon import declarations as declared
from vdnif_addon import settings
from vdnif_addon.cli import build_parser, show_default
from vdnif_addon.cli.options import validate_arguments
from vdnif_addon.errors import VDNIFError
from vdnif_addon.limits import check_image
from vdnif_addon.pose_sets import PoseSpec
from vdnif_addon.settings import RECIPE, NetworkConfig, TrainConfig
from vdnif_addon.training.fit import fit_model

_spec = importlib.util.spec_from_file_location("cli_docs", REPO / "tools" / "cli_docs.py")
cli_docs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cli_docs)

SAVED_RNA_NAMES = {
    "resolution", "pose_source", "pose_count", "seed", "max_angle", "rays_per_pose", "variant",
    "levels", "base_resolution", "log2_table_size", "feature_dim", "pe_bands", "width", "depth",
    "steps", "batch_size", "device", "precision", "image_width", "image_height", "eval_poses",
    "ao_samples", "ao_distance"}
"""The declared panel properties' RNA names as .blend files saved before the declarations
store them: a renamed one would lose a saved file's value."""

WORDED = {("resolution", command) for command in declared.RESOLUTION.option.commands} | {
    ("poses", "side-by-side"), ("seed", "side-by-side"), ("rays_per_pose", "train"),
    ("steps", "demo")}
"""(setting, command) whose option help the command words for itself."""

REQUIRED = {"dataset": ["--out", "d"], "train": ["--data", "d"], "render": ["--model", "m",
            "--out", "o"], "evaluate": ["--model", "m"], "experiment": ["static"]}
"""The arguments a command needs to parse."""

# Run after ENABLE_IN_FRESH_PROCESS: prints the registered properties as JSON, and what each
# number property holds after a value past either end of its hard range was set.
DUMP_RNA = f"""
import json

def described(prop):
    found = {{"type": prop.type, "name": prop.name, "description": prop.description,
              "subtype": prop.subtype}}
    if prop.type in ("BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"):
        found["default"] = prop.default
    if prop.type in ("INT", "FLOAT"):
        found["hard"] = [prop.hard_min, prop.hard_max]
        found["soft"] = [prop.soft_min, prop.soft_max]
    if prop.type == "FLOAT":
        found["precision"] = prop.precision
    if prop.type == "ENUM":
        found["items"] = [[item.identifier, item.value] for item in prop.enum_items]
    return found

rna = bpy.types.Object.bl_rna.properties["vdnif"].fixed_type
table = {{name: described(prop) for name, prop in rna.properties.items()
          if name != "rna_type" and not getattr(prop, "is_array", False)}}
mesh = bpy.data.meshes.new("m")
settings = bpy.data.objects.new("o", mesh).vdnif
for name, row in table.items():
    if row["type"] in ("INT", "FLOAT"):
        low, high = row["hard"]
        past = 1 if row["type"] == "INT" else (high - low) * 1e-3
        held = []
        for value in (low - past, high + past):
            if row["type"] == "INT" and not -2**31 <= value < 2**31:
                continue
            setattr(settings, name, value)
            held.append(getattr(settings, name))
        row["held"] = held
preferences = bpy.context.preferences.addons["{EXTENSION_MODULE}"].preferences
print(json.dumps([table, described(preferences.bl_rna.properties["device"])]))
"""


@pytest.fixture(scope="module")
def panel():
    """The registered RNA of ``Object.vdnif`` (name -> its type, label, tooltip, default,
    ranges, items) and of the preferences' device, read in a fresh Blender process that
    enables the extension, so this file keeps to one copy of the core in its own process
    (tests/project/test_module_identity.py)."""
    done = subprocess.run([sys.executable, "-c", ENABLE_IN_FRESH_PROCESS + DUMP_RNA],
                          capture_output=True, text=True, timeout=120, check=True)
    table, device = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(table) > 30                                        # the table was read
    return {name: types.SimpleNamespace(**row) for name, row in table.items()}, device


@pytest.fixture(scope="module")
def parser():
    return build_parser()


def command_parsers(parser):
    return next(action for action in parser._actions
                if isinstance(action, argparse._SubParsersAction)).choices


def action_of(parser, command, flag):
    return next(action for action in command_parsers(parser)[command]._actions
                if flag in action.option_strings)


def declared_options():
    """(setting, command) of every declared option, for parametrize."""
    return [pytest.param(setting, command, id=f"{command} {setting.option.flag}")
            for setting in declared.SETTINGS if setting.option is not None
            for command in setting.option.commands]


def numbers():
    return [pytest.param(setting, id=setting.name) for setting in declared.SETTINGS
            if setting.kind in (int, float)]


def test_declarations_are_whole():
    names = [setting.name for setting in declared.SETTINGS]
    assert len(names) == len(set(names)) > 20
    rna = [panel.rna for setting in declared.SETTINGS for panel in setting.panel]
    assert len(rna) == len(set(rna))
    for setting in declared.SETTINGS:
        assert setting.help and "\n" not in setting.help, setting.name
        if setting.kind in (int, float):
            values = [setting.default, *(p.default_of(setting) for p in setting.panel)]
            if setting.option is not None:
                values += [setting.option.default_for(setting, command)
                           for command in setting.option.commands]
            low, high = setting.range
            words = setting.option.words if setting.option is not None else ()
            assert all(low <= value <= high for value in values
                       if value is not None and value not in words), setting
        else:
            assert setting.default in setting.names, setting.name
    for command in command_parsers(build_parser()):
        flags = [setting.option.flag for setting in declared.command_options(command)]
        assert len(flags) == len(set(flags)), command


@pytest.mark.parametrize("setting, command", declared_options())
def test_each_declared_option_is_generated(parser, setting, command):
    option = setting.option
    action = action_of(parser, command, option.flag)
    assert action.dest == option.dest
    assert action.default == option.default_for(setting, command)
    assert action.metavar == option.metavar
    parsed_choices = setting.choices and option.parse_choices
    assert action.choices == (option.names(setting) if parsed_choices else None)
    if (setting.name, command) not in WORDED:
        assert action.help == (option.help or setting.help)
    else:
        assert action.help and action.help != setting.help
    if setting.kind in (int, float):        # the type parses the declared bounds
        argv = [command, *REQUIRED.get(command, []), f"{option.flag}={setting.high}"]
        assert getattr(parser.parse_args(argv), option.dest) == setting.high


def test_the_parsers_hold_no_undeclared_copy_of_a_setting(parser):
    """Where a command has a declared setting's flag, the declarations give it that option:
    no command adds one by hand past its declaration."""
    flags = {setting.option.flag for setting in declared.SETTINGS if setting.option}
    for name, command in command_parsers(parser).items():
        present = {flag for action in command._actions for flag in action.option_strings}
        wanted = {setting.option.flag for setting in declared.command_options(name)}
        assert present & flags == wanted, name


def test_a_new_declaration_reaches_the_parser_the_validation_and_the_doc(monkeypatch):
    """A setting declared with an option of two commands, and nothing else: both commands
    take it with its help and default, the validation refuses it past its range, and the
    doc generator writes its row."""
    new = declared.Setting("probe_count", int, 7, "probes per pixel", 1, 99,
                           option=declared.Option("--probe-count", ("capture", "evaluate"), "P"))
    monkeypatch.setattr(declared, "SETTINGS", (*declared.SETTINGS, new))
    parser = build_parser()
    for command in ("capture", "evaluate"):
        action = action_of(parser, command, "--probe-count")
        assert (action.default, action.help, action.metavar) == (7, "probes per pixel", "P")
        argv = [command, *REQUIRED.get(command, [])]
        assert parser.parse_args([*argv, "--probe-count", "99"]).probe_count == 99
        with pytest.raises(VDNIFError, match="--probe-count 100 is more than the limit 99"):
            validate_arguments(parser.parse_args([*argv, "--probe-count", "100"]))
    assert "--probe-count" not in {flag for action in command_parsers(parser)["render"]._actions
                                   for flag in action.option_strings}
    rows = cli_docs.tables(parser)["capture"]
    assert "| `--probe-count P` | 7 | probes per pixel |" in rows


@pytest.mark.parametrize("rna", sorted(declared.panel_properties()))
def test_each_declared_panel_property_is_generated(panel, rna):
    properties, _ = panel
    setting, declared_panel = declared.panel_properties()[rna]
    prop = properties[rna]
    assert (prop.name, prop.description) == (declared_panel.label, declared_panel.description)
    default = declared_panel.default_of(setting)
    assert prop.default == (pytest.approx(default) if setting.kind is float else default)
    if setting.choices:
        assert prop.type == "ENUM"
        items = [[item[0], item[3] if len(item) > 3 else None]
                 for item in setting.enum_items(declared_panel.extra)]
        assert [identifier for identifier, _ in prop.items] == [i for i, _ in items]
        assert all(value == number for (_, value), (_, number) in zip(prop.items, items)
                   if number is not None)
        return
    assert prop.type == {int: "INT", float: "FLOAT"}[setting.kind]
    assert prop.hard == pytest.approx(list(setting.range))
    # Blender holds a value set past the range at the bound (past a C int: not tried).
    assert prop.held == pytest.approx(list(setting.range)[:len(prop.held)]) and prop.held
    if declared_panel.soft_max is not None:
        assert prop.soft[1] == pytest.approx(declared_panel.soft_max)
    if declared_panel.subtype is not None:
        assert prop.subtype == declared_panel.subtype
    if declared_panel.precision is not None:
        assert prop.precision == declared_panel.precision


def test_the_declared_panel_properties_keep_their_saved_names(panel):
    assert SAVED_RNA_NAMES <= set(declared.panel_properties())
    assert SAVED_RNA_NAMES <= set(panel[0])


def test_the_preferences_device_is_the_declared_choices(panel):
    _, device = panel
    assert [identifier for identifier, _ in device["items"]] == list(declared.DEVICE.names)
    assert device["default"] == declared.DEVICE.default == TrainConfig().device


def test_the_doc_tables_are_the_generators():
    """docs/cli.md's option tables are what ``tools/cli_docs.py --write`` writes, and each row
    of a declared option gives its declared default and help."""
    text = (REPO / "docs" / "cli.md").read_text()
    assert cli_docs.rewrite(text, cli_docs.tables()) == text, \
        "docs/cli.md differs from its generator: run python tools/cli_docs.py --write"
    rows, heading, fenced = {}, None, False
    for line in text.splitlines():
        fenced ^= line.startswith("```")
        if line.startswith("#") and not fenced:
            heading = line.lstrip("#").strip()
        elif line.startswith("| `--"):
            cells = [cell.strip() for cell in line.strip("|").split(" | ")]
            rows[heading, cells[0].strip("`").split()[0]] = cells
    for setting in declared.SETTINGS:
        if setting.option is None:
            continue
        for command in setting.option.commands:
            spec, default, what = rows[command, setting.option.flag]
            value = setting.option.default_for(setting, command)
            if value is not None:
                assert default == show_default(value), (command, spec)
            if (setting.name, command) not in WORDED:
                assert what == (setting.option.help or setting.help).replace("|", "\\|").split(
                    " (default")[0], (command, spec)


def test_a_changed_doc_row_fails_the_check(tmp_path):
    text = (REPO / "docs" / "cli.md").read_text()
    changed = text.replace("| `--levels L` | the variant's |", "| `--levels L` | 2 |")
    assert changed != text
    assert cli_docs.rewrite(changed, cli_docs.tables()) != changed
    assert cli_docs.rewrite(changed, cli_docs.tables()) == text


def test_the_core_defaults_are_the_declared_ones():
    network, train, spec = NetworkConfig(), TrainConfig(), PoseSpec()
    core = {**{name: getattr(config, name) for config in (network, train, RECIPE)
               for name in CONFIG_FIELDS[type(config)]},
            "pose_source": spec.source,
            "max_angle": spec.max_angle_deg, "evaluation_poses": spec.count,
            "ao_samples": settings.AO_SAMPLES, "ao_distance": settings.AO_DISTANCE,
            "precision": settings.DEFAULT_PRECISION, "variant": settings.AUTO_VARIANT,
            "image_width": settings.COMMAND_IMAGE[0], "image_height": settings.COMMAND_IMAGE[1],
            "group_timeout_s": inspect.signature(fit_model).parameters[
                "group_timeout_s"].default}
    for setting in declared.SETTINGS:
        assert core[setting.name] == setting.default, setting.name
    assert (train.steps, train.batch_size) == (declared.STEPS.default,
                                                declared.BATCH_SIZE.default)


def _tetrahedron():
    return (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float),
            np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))


def _rays(name, value):
    from vdnif_addon.tracing.rays import training_rays

    shares = {"surface_fraction": 0.0, "grazing_fraction": 0.0, "secondary_fraction": 0.0,
              name: value}
    points = np.zeros((1, 3))
    training_rays(np.zeros(3), np.ones(3), points, 1, shares.pop("surface_fraction"),
                  np.random.default_rng(0), surface_normals=np.array([[0.0, 0.0, 1.0]]),
                  **shares)


def _secondary(**values):
    from vdnif_addon.inference.secondary import SecondarySettings

    SecondarySettings(**values)


CONFIG_FIELDS = {config: {field.name for field in dataclasses.fields(config)}
                 for config in (NetworkConfig, TrainConfig, type(RECIPE))}
# The core's own check of each setting outside NetworkConfig and TrainConfig (whose fields
# check themselves): a call that raises VDNIFError for a refused value (None: the setting
# reaches the core only through a checked command or panel).
CORE = {
    "resolution": lambda value: __import__("vdnif_addon.geometry.voxels", fromlist=["x"])
    .build_grid(*_tetrahedron(), value),
    "poses": lambda value: PoseSpec(count=value),
    "evaluation_poses": lambda value: PoseSpec(count=value),
    "max_angle": lambda value: PoseSpec(max_angle_deg=value),
    "rays_per_pose": None,
    "surface_fraction": lambda value: _rays("surface_fraction", value),
    "grazing_fraction": lambda value: _rays("grazing_fraction", value),
    "secondary_fraction": lambda value: _rays("secondary_fraction", value),
    "ao_samples": lambda value: _secondary(samples=value),
    "ao_distance": lambda value: _secondary(distance=value),
    "image_width": lambda value: check_image(value, 1),
    "image_height": lambda value: check_image(1, value),
    "group_timeout_s": lambda value: __import__(
        "vdnif_addon.training.distributed", fromlist=["x"]).check_group_timeout(value),
}
ALONE = {"base_resolution": {"levels": 1, "normal_levels": 1}, "levels": {"growth": 1.0},
         "normal_levels": {"growth": 1.0}}
"""One level for the largest base resolution, no growth for the most levels: else the
finest level passes its own cap first."""
EXPENSIVE = {"resolution"}
"""Settings whose upper bound the core is not asked to take (a 256^3 voxel grid)."""


def core_refuses(name, value):
    if name in CORE:
        check = CORE[name]
    elif name in CONFIG_FIELDS[NetworkConfig]:
        def check(value):
            NetworkConfig(**{name: value, **ALONE.get(name, {})})
    else:
        def check(value):
            TrainConfig(**{name: value})
    if check is None:
        return None
    try:
        check(value)
    except VDNIFError:
        return True
    return False


def refused(parser, command, option, value):
    """Whether ``command option value`` fails its validation (or its parsing)."""
    try:
        validate_arguments(parser.parse_args([command, *REQUIRED.get(command, []),
                                              f"{option}={value}"]))
    except VDNIFError:
        return True
    return False


@pytest.mark.parametrize("setting", numbers())
def test_the_declared_range_is_enforced_by_the_parser_and_the_core(parser, setting):
    """The panel's half: test_each_declared_panel_property_is_generated (the registered hard
    range, and what a property holds when set past it)."""
    low, high = setting.range
    step = 1 if setting.kind is int else (high - low) * 1e-6
    if setting.option is not None:
        command = setting.option.commands[0]
        flag = setting.option.flag
        assert not refused(parser, command, flag, low) and not refused(parser, command, flag,
                                                                       high)
        assert refused(parser, command, flag, low - step)
        assert refused(parser, command, flag, high + step)
    if core_refuses(setting.name, low) is not None:
        assert not core_refuses(setting.name, low)
        assert setting.name in EXPENSIVE or not core_refuses(setting.name, high)
        assert core_refuses(setting.name, low - step)
        assert core_refuses(setting.name, high + step)


def test_every_number_is_checked_somewhere():
    """Each numeric setting reaches the user through an option or a panel property, and the
    core checks it unless it names why not (CORE's None)."""
    for setting in declared.SETTINGS:
        if setting.kind in (int, float):
            assert setting.option is not None or setting.panel, setting.name
            assert setting.name in CORE or any(
                setting.name in CONFIG_FIELDS[config] for config in (NetworkConfig, TrainConfig))


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


def test_a_declared_train_option_of_a_config_field_reaches_the_training(monkeypatch):
    """``train``'s declared options that name a NetworkConfig or TrainConfig field are the
    training's overrides: a new one needs no line of command code."""
    from vdnif_addon.cli.options import network_overrides
    from vdnif_addon.model.variants import variant_config

    new = declared.Setting("lr_mlp", float, 2e-2, "the MLP's learning rate", 1e-6, 1.0,
                           option=declared.Option("--lr-mlp", ("train",), "LR"))
    monkeypatch.setattr(declared, "SETTINGS", (*declared.SETTINGS, new))
    args = build_parser().parse_args(["train", "--data", "d", "--lr-mlp", "0.005",
                                      "--levels", "3", "--steps", "7"])
    overrides = network_overrides(args)
    assert {name: overrides[name] for name in ("lr_mlp", "levels", "steps", "seed")} == {
        "lr_mlp": 0.005, "levels": 3, "steps": 7, "seed": 0}
    assert "growth" not in overrides                    # not given: the variant's own
    chosen = variant_config("proposed", **overrides)
    assert (chosen.train.lr_mlp, chosen.network.levels, chosen.train.steps) == (0.005, 3, 7)
