"""The batch commands' shared option groups (scene, poses, capture, device, training,
network) and what turns them into work: the scene they name, the pose spec, the resolution
(``auto`` included), the checks of every option before any work, and the summary lines that
several commands print. A setting's option is generated from its declaration
(``add_setting``, ``declarations``), and checked against its declared range."""

import argparse
import dataclasses
import math
import pathlib
import sys

from .. import declarations as declared
from ..errors import VDNIFError
from ..extreme_deform import ExtremeDeform, parse_scale
from ..pose_sets import POSE_SETS, TEST_POSES, PoseSpec
from ..settings import (
    AUTO_RESOLUTION,
    DEMO_SCENES,
    MAX_RESOLUTION,
    MIN_RESOLUTION,
    RECIPE,
    RECIPE_RESOLUTION,
    RIGS,
    NetworkConfig,
    TrainConfig,
)
from ..text import (
    EMBREE_NOTE,
    exact_speed_line,
    metrics_line,
    secondary_line,
    shaded_line,
    speed_line,
)
from .outputs import check_outputs, names_scene  # noqa: F401 - names_scene for the commands

PIPELINE_SCENE = "arm"
"""The embedded scene of a pipeline command that names no scene."""


def add_scene_options(parser):
    """``--scene NAME | --mesh FILE --rig R | --blend FILE --object NAME``."""
    group = parser.add_argument_group("scene (one of)")
    source = group.add_mutually_exclusive_group()
    source.add_argument("--scene", choices=DEMO_SCENES,
                        help=f"an embedded demo scene (default: {PIPELINE_SCENE})")
    source.add_argument("--mesh", type=pathlib.Path, metavar="FILE",
                        help="an OBJ, PLY, glTF or FBX file: its own armature, else --rig")
    source.add_argument("--blend", type=pathlib.Path, metavar="FILE",
                        help="a .blend file; the object is --object or the active one")
    group.add_argument("--rig", choices=RIGS, help="procedural rig of a --mesh without one, or "
                       "of a scene (default: armature for such a mesh, else the scene's)")
    group.add_argument("--object", metavar="NAME",
                       help="the mesh object in --blend (default: the active one)")


def add_stress_options(parser):
    """Adds ``--scale S`` and ``--deform KIND:VALUE`` (``blender/extremes.py`` applies them)
    to an argparse parser (bad values raise VDNIFError while parsing)."""
    group = parser.add_argument_group("stress", description=(
        "Errors in object units should not change with --scale. Bend and twist are summed "
        "along the bone chain or the lattice's longest axis; stretch and squash keep the "
        "cross-section (no volume preservation)."))
    group.add_argument("--scale", type=parse_scale, default=1.0, metavar="S",
                       help="make the object's rest geometry and rig S times larger before "
                            "capture")
    group.add_argument("--deform", type=ExtremeDeform.parse, metavar="KIND:VALUE",
                       help="an extreme pose on top of every pose of the rig: bend:DEG, "
                            "twist:DEG, stretch:X (X >= 1) or squash:X (0 < X <= 1)")


def load_scene(args):
    """Builds or opens the scene the options name and returns the mesh object."""
    from ..blender import scenes

    if args.mesh is not None:
        return scenes.mesh_scene(args.mesh, args.rig)
    if args.blend is not None:
        return scenes.blend_scene(args.blend, args.object)
    return scenes.demo_scene(args.scene or PIPELINE_SCENE, rig=args.rig)


def load_posed_scene(args, check=None):
    """(mesh object, PoseSpec): the scene of the options with ``--scale`` applied and
    ``--deform`` carried by the pose spec; ``check(obj)``, where given, refuses what the
    object makes wrong before its resolution is suggested (seconds of work)."""
    from ..blender.extremes import apply_stress

    obj = load_scene(args)
    spec = apply_stress(args, obj, pose_spec(args))
    if check is not None:
        check(obj)
    if getattr(args, "resolution", None) == AUTO_RESOLUTION:     # the scene commands' default
        suggestion = suggested_resolution(obj, spec)
        args.resolution, args.resolution_suggestion = suggestion.resolution, suggestion.record()
    elif getattr(args, "resolution", None) == RECIPE_RESOLUTION:
        from ..blender.resolution import recipe_resolution

        args.resolution = recipe_resolution(obj)
    return obj, spec


def suggested_resolution(obj, spec):
    """``--resolution auto``: the suggestion for the scene (``blender/resolution``), with
    the embedding errors that decided it on stderr."""
    from ..blender.resolution import suggest_resolution

    suggestion = suggest_resolution(obj, spec)
    print(f"resolution auto for '{obj.name}': {suggestion.describe()}", file=sys.stderr)
    return suggestion


def with_suggestion(args, data):
    """``data`` with the suggestion that chose ``--resolution auto`` (its curve, knee and
    floor: ``Suggestion.record``) under ``resolution_suggestion``, where one did."""
    suggestion = getattr(args, "resolution_suggestion", None)
    return data if suggestion is None else {**data, "resolution_suggestion": suggestion}


def resolution_option(text):
    """``--resolution``: an integer, ``auto`` (the suggested resolution) or ``recipe`` (the
    recipe's fixed one)."""
    words = declared.RESOLUTION.option.words
    if text in words:
        return text
    try:
        return int(text)
    except ValueError:
        named = " or ".join(f"'{word}'" for word in words)
        raise argparse.ArgumentTypeError(
            f"expected an integer, {named}, got {text!r}") from None


def add_setting(parser, setting, command, **words):
    """Adds the option that ``setting`` declares (``declarations.Option``) to ``parser`` (or
    an argument group) as ``command`` takes it: its flag, metavar, default, help, and its
    type or choices; ``words`` are add_argument keywords the command words for itself (a
    help that says what the setting means there, a type that also takes 'auto')."""
    option = setting.option
    if option is None or command not in option.commands:
        raise ValueError(f"setting {setting.name} is not declared as an option of {command}")
    keywords = {"default": option.default_for(setting, command),
                "help": option.help or setting.help}
    if option.metavar is not None:
        keywords["metavar"] = option.metavar
    if setting.kind is bool:
        keywords["action"] = "store_true"
    elif setting.choices and option.parse_choices:
        keywords["choices"] = option.names(setting)
    else:
        keywords["type"] = setting.kind
    return parser.add_argument(option.flag, **{**keywords, **words})


def add_declared_options(parser, command):
    """Adds each option the declarations give ``command`` that its parser has not placed yet,
    in the option group it declares (made where missing), so that a newly declared setting's
    option appears without a line of parser code; returns their flags."""
    placed = {flag for action in parser._actions for flag in action.option_strings}
    added = []
    for setting in declared.command_options(command):
        if setting.option.flag in placed:
            continue
        group = parser
        if setting.option.group:
            group = next((group for group in parser._action_groups
                          if group.title == setting.option.group), None) \
                or parser.add_argument_group(setting.option.group)
        add_setting(group, setting, command)
        added.append(setting.option.flag)
    return added


def add_pose_options(parser, command):
    group = parser.add_argument_group("poses")
    for setting in (declared.POSES, declared.POSE_SOURCE, declared.SEED, declared.MAX_ANGLE):
        add_setting(group, setting, command)


def add_pose_set_option(parser):
    """``--pose-set``: which set of unseen poses a command on them takes (DESIGN section 4:
    development poses serve choices, test poses the reported figures)."""
    parser.add_argument("--pose-set", choices=tuple(POSE_SETS), default=TEST_POSES,
                        help="the unseen poses: the test set, reported; or the "
                             "development set, for choices (default test)")


def asked_pose_set(args):
    """The set of unseen poses the options ask for: None for views of the rest pose
    (``--rest-pose``), the test set where the options hold no ``--pose-set`` (a tool's)."""
    return None if getattr(args, "rest_pose", False) else getattr(args, "pose_set", TEST_POSES)


def pose_spec(args):
    return PoseSpec(source=args.pose_source, count=args.poses, seed=args.seed,
                    max_angle_deg=args.max_angle)


def add_capture_options(parser, command):
    add_setting(parser, declared.RESOLUTION, command, type=resolution_option,
                help=f"voxels along the longest side ({MIN_RESOLUTION}..{MAX_RESOLUTION}); "
                f"'{AUTO_RESOLUTION}': the coarsest that follows the mesh and its thin parts; "
                f"'{RECIPE_RESOLUTION}': {RECIPE.resolution}, {RECIPE.textured_resolution} "
                f"textured, as the paper's experiments (default: {AUTO_RESOLUTION})")
    add_pose_options(parser, command)


SECONDARY_HELP = ("also the ambient-occlusion and shadow passes (light: the scene's first sun "
                  "or point light, else a default direction)")
SHADED_HELP = ("also the ambient-occlusion, shadow and shaded passes (light: the scene's "
               "first sun or point light, else a default direction; ambient: its world)")


def add_secondary_options(parser, command, secondary_help=SECONDARY_HELP):
    """``--secondary`` with ``--ao-samples`` and ``--ao-distance``: the AO and shadow rays
    (``secondary_help`` says what ``--secondary`` does in the command)."""
    group = parser.add_argument_group("secondary rays")
    group.add_argument("--secondary", action="store_true", help=secondary_help)
    add_setting(group, declared.AO_SAMPLES, command)
    add_setting(group, declared.AO_DISTANCE, command)


def secondary_settings(args, obj):
    """The ``SecondarySettings`` of the options, the light read from the scene of ``obj``;
    None without ``--secondary``."""
    if not getattr(args, "secondary", False):
        return None
    import bpy

    from ..blender.lights import scene_secondary

    return scene_secondary(bpy.context.scene, obj, samples=args.ao_samples,
                           distance=args.ao_distance)


def add_image_options(parser, command):
    """``--width W --height H``: the image's size in pixels."""
    add_setting(parser, declared.IMAGE_WIDTH, command)
    add_setting(parser, declared.IMAGE_HEIGHT, command)


def add_training_options(parser):
    for setting in (declared.STEPS, declared.BATCH_SIZE, declared.GROUP_TIMEOUT,
                    declared.DEVICE):
        add_setting(parser, setting, "train")


def add_network_options(parser):
    """``train``'s options of the encoding and network, each the variant's unless given."""
    group = parser.add_argument_group(declared.NETWORK_GROUP)
    for setting in declared.command_options("train", declared.NETWORK_GROUP):
        add_setting(group, setting, "train")


def write_json(path, data):
    """Writes ``data`` as strict JSON to ``path`` atomically (``safe_io``: no half-written
    file, no write through a symlink, no NaN), a mapping with its provenance (the commit,
    the network its figures describe: a report's model's, ``config["network"]``, else
    today's default; the recipe, the machine: its figures include times)."""
    from ..model.provenance import stamp
    from ..output_rule import REPORT_FORMAT
    from ..safe_io import write_json_atomic

    if path is not None:
        if isinstance(data, dict):
            data = stamp({"format": REPORT_FORMAT, **data} if "format" not in data else data,
                         with_machine=True)
        write_json_atomic(path, data)


def check_resolution(value):
    if value is None or value in declared.RESOLUTION.option.words:   # resolved with the scene
        return
    if not MIN_RESOLUTION <= value <= MAX_RESOLUTION:
        raise VDNIFError(f"resolution {value} is outside {MIN_RESOLUTION}..{MAX_RESOLUTION}")


def network_overrides(args):
    """The NetworkConfig / TrainConfig fields that ``train``'s declared options set: each
    one given (the network's are None, the variant's own, unless given)."""
    fields = {field.name for config in (NetworkConfig, TrainConfig)
              for field in dataclasses.fields(config)}
    return {setting.name: getattr(args, setting.option.dest)
            for setting in declared.command_options("train")
            if setting.name in fields and getattr(args, setting.option.dest) is not None}


def report_training(record):
    """The progress line: the task losses and their sum, as the panel shows it (the weighted
    objective that training minimizes goes negative with the learned weights)."""
    losses = ", ".join(f"{k} {v:.4f}" for k, v in record["losses"].items())
    total = sum(record["losses"].values())
    print(f"train: step {record['step']}/{record['steps']}, loss {total:.4f} "
          f"({losses}), {record['samples_per_s']:,.0f} samples/s, "
          f"ETA {record['eta_s']:.0f} s", file=sys.stderr, flush=True)


def print_evaluation(report):
    print(f"evaluated {report['variant']} on '{report['object']}' R={report['resolution']}, "
          f"{report['poses']} {'unseen ' if report['unseen_poses'] else ''}poses, "
          f"{report['width']}x{report['height']}")
    for name in ("vs_true", "vs_embedded"):
        print(f"  {name.replace('_', ' ')}: {metrics_line(report[name])}")
    if "secondary" in report:
        print(f"  secondary rays ({report['secondary']['light']}): "
              + "; ".join(f"{name.replace('_', ' ')} {secondary_line(report[name])}"
                          for name in ("vs_true", "vs_embedded")))
        band = report["secondary"].get("terminator_band")
        if "shaded_psnr" in report["vs_true"]:
            print(f"  shaded image vs true (terminator band |N.L| < {band}): "
                  f"{shaded_line(report['vs_true'])}")
    t = report["timings"]
    print(f"  pose preparation {t['prepare_pose_s'] * 1e3:.1f} ms, model "
          f"{report['model_bytes']:,} bytes")
    print(f"  speed on the same rays: network {speed_line(report)}; "
          f"{exact_speed_line(report)}")
    print(f"  {EMBREE_NOTE}")


IMAGE_COMMANDS = declared.IMAGE_COMMANDS


def frames_option(text: str) -> list[int]:
    """The type of ``render --frames A:B[:STEP]``: the frames, A to B included."""
    from ..posed.animation import parse_frames

    try:
        return parse_frames(text)
    except VDNIFError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--frames '{text}' ")) from None


def validate_arguments(args):
    """Checks every option that can be wrong on its own, and every input and output place,
    before any work: the first problem raises VDNIFError (``limits`` holds the caps)."""
    from .. import limits
    from ..mesh_input import check_input, check_mesh_file
    from ..safe_io import open_regular

    def given(name):
        return getattr(args, name, None) is not None

    def at_least(name, low, high=None):
        if given(name):
            limits.check_range(f"--{name.replace('_', '-')}", getattr(args, name), low, high)

    if given("mesh"):                   # it and the files it names, its header's counts
        check_mesh_file(args.mesh)
    if given("blend"):
        check_input(args.blend, "blend file")
    check_settings(args)
    at_least("repeats", 1, limits.MAX_REPEATS)
    at_least("seeds", 1, limits.MAX_REPEATS)
    at_least("threads", 1, limits.MAX_THREADS)
    at_least("preview", 1, limits.MAX_IMAGE_SIDE)
    if given("frame") and not math.isfinite(args.frame):
        raise VDNIFError(f"--frame {args.frame} is not a finite number")
    if given("frame") and abs(args.frame) > limits.MAX_FRAME:
        raise VDNIFError(f"--frame {args.frame:g} is outside Blender's frames "
                         f"{-limits.MAX_FRAME}..{limits.MAX_FRAME}")
    if args.command in IMAGE_COMMANDS and given("width") and given("height"):
        limits.check_image(args.width, args.height)
    if isinstance(getattr(args, "model", None), pathlib.Path):
        # the loader's own first check, before torch and bpy are imported
        with open_regular(args.model, f"model file {args.model}"):
            pass
    check_outputs(args)
    if args.command == "train" and not given("data") and not names_scene(args):
        raise VDNIFError("give --data DIR (a dataset folder) or scene options "
                         "(--scene, --mesh or --blend)")


def check_settings(args):
    """Each declared setting that the command took within its declared range or choices, the
    one range of the setting (``declarations``): the first one outside raises VDNIFError."""
    from .. import limits

    for setting in declared.command_options(args.command):
        option = setting.option
        value = getattr(args, option.dest, None)
        label = option.label or option.flag
        if value is None:
            continue
        if setting is declared.RESOLUTION:
            if isinstance(value, int):               # not 'auto'
                check_resolution(value)
        elif setting.kind is int:
            limits.check_range(label, value, *setting.range)
        elif setting.kind is float:
            low, high = setting.range
            if not (math.isfinite(value) and low <= value <= high):
                raise VDNIFError(f"{label} {value} must be a number in {low:g}..{high:g}")
        elif setting.choices and value not in option.names(setting):
            raise VDNIFError(f"{label} '{value}' must be one of "
                             f"{', '.join(map(repr, option.names(setting)))}")
