"""The batch commands' shared option groups (scene, poses, capture, device, training,
network) and what turns them into work: the scene they name, the pose spec, the resolution
(``auto`` included), the checks of every option before any work, and the summary lines that
several commands print."""

import argparse
import math
import os
import pathlib
import sys

from ..errors import VDNIFError
from ..extreme_deform import ExtremeDeform, parse_scale
from ..pose_sets import PoseSpec
from ..settings import (
    ALBEDO_MODES,
    AO_DISTANCE,
    AO_SAMPLES,
    AUTO_RESOLUTION,
    BOUNDS,
    DEFAULT_DEVICE,
    DEFAULT_PRECISION,
    DEMO_SCENES,
    DEVICES,
    MAX_RESOLUTION,
    MIN_RESOLUTION,
    NORMAL_MODES,
    PE_SCALES,
    POSE_SOURCES,
    PRECISIONS,
    RECIPE,
    RIGS,
)
from ..text import metrics_line, secondary_line, speed_line

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
    group.add_argument("--rig", choices=RIGS,
                       help="procedural rig of a --mesh without one (default armature) or a scene")
    group.add_argument("--object", metavar="NAME", help="the mesh object in --blend")


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


def load_posed_scene(args):
    """(mesh object, PoseSpec): the scene of the options with ``--scale`` applied and
    ``--deform`` carried by the pose spec."""
    from ..blender.extremes import apply_stress

    obj = load_scene(args)
    spec = apply_stress(args, obj, pose_spec(args))
    if getattr(args, "resolution", None) == AUTO_RESOLUTION:
        args.resolution = suggested_resolution(obj, spec)
    elif hasattr(args, "resolution") and args.resolution is None:   # not given, no model
        from ..blender.resolution import recipe_resolution

        args.resolution = recipe_resolution(obj)
    return obj, spec


def suggested_resolution(obj, spec):
    """``--resolution auto``: the suggested resolution of the scene (``blender/resolution``),
    with the embedding errors that decided it on stderr."""
    from ..blender.resolution import suggest_resolution

    suggestion = suggest_resolution(obj, spec)
    print(f"resolution auto for '{obj.name}': {suggestion.describe()}", file=sys.stderr)
    return suggestion.resolution


def resolution_option(text):
    """``--resolution``: an integer, or ``auto`` (the suggested resolution)."""
    if text == AUTO_RESOLUTION:
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an integer or '{AUTO_RESOLUTION}', got {text!r}") from None


def add_pose_options(parser, default_poses=8):
    group = parser.add_argument_group("poses")
    group.add_argument("--poses", type=int, default=default_poses, metavar="N",
                       help=f"number of poses (default {default_poses})")
    group.add_argument("--pose-source", choices=POSE_SOURCES, default=PoseSpec.source,
                       help="random bone rotations / lattice offsets, or timeline frames")
    group.add_argument("--seed", type=int, default=PoseSpec.seed, help="random pose seed")
    group.add_argument("--max-angle", type=float, default=PoseSpec.max_angle_deg, metavar="DEG",
                       help="largest random bone rotation per axis where the bone has no "
                            "rotation limits")


def pose_spec(args):
    return PoseSpec(source=args.pose_source, count=args.poses, seed=args.seed,
                    max_angle_deg=args.max_angle)


def add_capture_options(parser, default_poses):
    parser.add_argument("--resolution", type=resolution_option, metavar="R",
                        help=f"voxels along the longest side ({MIN_RESOLUTION}.."
                        f"{MAX_RESOLUTION}), or '{AUTO_RESOLUTION}' to suggest one (default "
                        f"{RECIPE.resolution}, {RECIPE.textured_resolution} for a textured "
                        "mesh)")
    add_pose_options(parser, default_poses)


SECONDARY_HELP = ("also the ambient-occlusion and shadow passes (light: the scene's first sun "
                  "or point light, else a default direction)")


def add_secondary_options(parser, secondary_help=SECONDARY_HELP):
    """``--secondary`` with ``--ao-samples`` and ``--ao-distance``: the AO and shadow rays
    (``secondary_help`` says what ``--secondary`` does in the command)."""
    group = parser.add_argument_group("secondary rays")
    group.add_argument("--secondary", action="store_true", help=secondary_help)
    group.add_argument("--ao-samples", type=int, default=AO_SAMPLES, metavar="N",
                       help="ambient-occlusion rays per pixel")
    group.add_argument("--ao-distance", type=float, default=AO_DISTANCE, metavar="D",
                       help="how far an ambient-occlusion ray looks, in object units")


def secondary_settings(args, obj):
    """The ``SecondarySettings`` of the options, the light read from the scene of ``obj``;
    None without ``--secondary``."""
    if not getattr(args, "secondary", False):
        return None
    import bpy

    from ..blender.lights import scene_light
    from ..inference.secondary import SecondarySettings

    return SecondarySettings(samples=args.ao_samples, distance=args.ao_distance,
                             light=scene_light(bpy.context.scene, obj))


def add_device_option(parser, default=DEFAULT_DEVICE):
    """``--device auto|cpu|cuda`` (settings.DEVICES): auto takes CUDA where torch has it."""
    parser.add_argument("--device", choices=DEVICES, default=default,
                        help=f"where the network runs (default {default})")


def add_precision_option(parser):
    """``--precision float32|bfloat16`` (settings.PRECISIONS): the arithmetic of the MLPs."""
    parser.add_argument("--precision", choices=PRECISIONS, default=DEFAULT_PRECISION,
                        help="the network MLPs' arithmetic: bfloat16 is faster where the device "
                             f"has it, a little less exact (default {DEFAULT_PRECISION})")


def add_training_options(parser):
    parser.add_argument("--steps", type=int, default=RECIPE.steps, metavar="N",
                        help=f"optimizer steps at most; training stops sooner once the "
                        f"held-out poses stop improving (default {RECIPE.steps})")
    parser.add_argument("--batch", type=int, default=RECIPE.batch_size, metavar="B",
                        help=f"segments per step and process (default {RECIPE.batch_size})")
    add_device_option(parser)


def write_json(path, data):
    """Writes ``data`` as strict JSON to ``path`` atomically (``safe_io``: no half-written
    file, no write through a symlink, no NaN)."""
    from ..safe_io import write_json_atomic

    if path is not None:
        write_json_atomic(path, data)


def check_resolution(value):
    if value in (AUTO_RESOLUTION, None):   # resolved once the scene is loaded
        return
    if not MIN_RESOLUTION <= value <= MAX_RESOLUTION:
        raise VDNIFError(f"resolution {value} is outside {MIN_RESOLUTION}..{MAX_RESOLUTION}")


NETWORK_OPTIONS = {   # option: (NetworkConfig field, type, help)
    "--levels": ("levels", int, "hash-grid levels L"),
    "--base-resolution": ("base_resolution", int, "coarsest hash-grid resolution N_min"),
    "--growth": ("growth", float, "resolution growth factor b between levels"),
    "--log2-table-size": ("log2_table_size", int, "hash table size 2^T per level"),
    "--feature-dim": ("feature_dim", int, "features per hash-grid entry Fd"),
    "--pe-bands": ("pe_bands", int, "positional-encoding bands F (0: plain LSNIF grid)"),
    "--pe-form": ("pe_form", str, "sin(2^k x) ('paper') or sin(pi 2^k x) ('pi')"),
    "--width": ("width", int, "MLP width"),
    "--depth": ("depth", int, "MLP hidden layers"),
    "--albedo-mode": ("albedo_mode", str, "albedo from the MLP over the segment ('segment') "
                      "or from a field of the rest point read at the placed hit ('hit')"),
    "--normal-mode": ("normal_mode", str, "normal from the MLP over the segment ('segment') "
                      "or from a field of the rest point read at the placed hit ('hit')"),
    "--normal-levels": ("normal_levels", int, "the normal field's hash-grid levels"),
    "--normal-log2-table-size": ("normal_log2_table_size", int,
                                 "the normal field's hash table size 2^T per level"),
}


def network_overrides(args):
    """NetworkConfig / TrainConfig fields set on the command line."""
    overrides = {field: getattr(args, option[2:].replace("-", "_"))
                 for option, (field, _, _) in NETWORK_OPTIONS.items()
                 if getattr(args, option[2:].replace("-", "_")) is not None}
    overrides.update(steps=args.steps, batch_size=args.batch, device=args.device,
                     seed=args.seed)
    return overrides


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
    t = report["timings"]
    print(f"  pose preparation {t['prepare_pose_s'] * 1e3:.1f} ms, model "
          f"{report['model_bytes']:,} bytes, render {speed_line(report)}")


def names_scene(args):
    """Whether the options name a scene (--scene, --mesh or --blend)."""
    return any(getattr(args, name) is not None for name in ("scene", "mesh", "blend"))


OUTPUT_FILES = ("json", "markdown", "results", "presets", "performance")
"""Options naming a file a command writes; ``--out`` is a file for train, else a folder."""
IMAGE_COMMANDS = ("references", "render", "evaluate", "side-by-side")
"""Commands whose --width/--height are an image's (train's --width is the MLP's)."""


def frames_option(text: str) -> list[int]:
    """The type of ``render --frames A:B[:STEP]``: the frames, A to B included."""
    from ..blender.animation import parse_frames

    try:
        return parse_frames(text)
    except VDNIFError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--frames '{text}' ")) from None


def output_file(text: str) -> pathlib.Path:
    """The type of an option that names an output file (--json, --markdown, train's --out):
    refused when it names a folder (a trailing separator, ``.``, ``..``), which the path
    object alone would drop, silently writing a file of the folder's name."""
    if text.replace(os.sep, "/").rpartition("/")[2] in ("", ".", ".."):
        raise argparse.ArgumentTypeError(f"'{text}' names a folder, not a file")
    return pathlib.Path(text)


def validate_arguments(args):
    """Checks every option that can be wrong on its own, and every input and output place,
    before any work: the first problem raises VDNIFError (``limits`` holds the caps)."""
    from .. import limits
    from ..safe_io import check_input_file, check_output_file, check_output_folder, open_regular

    def given(name):
        return getattr(args, name, None) is not None

    def at_least(name, low, high=None, label=None):
        if given(name):
            limits.check_range(label or f"--{name.replace('_', '-')}", getattr(args, name),
                               low, high)

    for name in ("mesh", "blend"):
        if given(name):
            check_input_file(getattr(args, name), f"{name} file")
    at_least("seed", *BOUNDS["seed"])
    at_least("poses", *BOUNDS["poses"])
    at_least("rays_per_pose", *BOUNDS["rays_per_pose"], "rays per pose")
    at_least("repeats", 1, limits.MAX_REPEATS)
    at_least("seeds", 1, limits.MAX_REPEATS)
    at_least("threads", 1, limits.MAX_THREADS)
    at_least("batch", *BOUNDS["batch_size"])
    at_least("steps", *BOUNDS["steps"])
    at_least("ao_samples", *BOUNDS["ao_samples"])
    at_least("preview", *BOUNDS["image_side"])
    if isinstance(getattr(args, "resolution", None), int):
        check_resolution(args.resolution)
    for name in ("surface_fraction", "grazing_fraction", "secondary_fraction", "max_angle",
                 "ao_distance"):
        low, high = BOUNDS[name]
        value = getattr(args, name, None)
        if value is not None and not (math.isfinite(value) and low <= value <= high):
            raise VDNIFError(f"--{name.replace('_', '-')} {value} must be a number in "
                             f"{low:g}..{high:g}")
    if given("frame") and not math.isfinite(args.frame):
        raise VDNIFError(f"--frame {args.frame} is not a finite number")
    if given("frame") and abs(args.frame) > limits.MAX_FRAME:
        raise VDNIFError(f"--frame {args.frame:g} is outside Blender's frames "
                         f"{-limits.MAX_FRAME}..{limits.MAX_FRAME}")
    if args.command in IMAGE_COMMANDS and given("width") and given("height"):
        limits.check_image(args.width, args.height)
    if args.command == "train":
        _validate_network_options(args, limits)
    if isinstance(getattr(args, "model", None), pathlib.Path):
        # the loader's own first check, before torch and bpy are imported
        with open_regular(args.model, f"model file {args.model}"):
            pass
    for name in OUTPUT_FILES:
        if given(name):
            check_output_file(getattr(args, name), f"--{name}")
    if args.command == "train" and given("data") and names_scene(args):
        check_output_folder(args.data, "--data folder")
    if given("out"):
        if args.command == "train":
            check_output_file(args.out, "--out model file")
        else:
            check_output_folder(args.out, "--out folder")
    if given("work"):
        check_output_folder(args.work, "--work folder")
    if args.command == "train" and not given("data") and not names_scene(args):
        raise VDNIFError("give --data DIR (a dataset folder) or scene options "
                         "(--scene, --mesh or --blend)")


def _validate_network_options(args, limits):
    for name in ("levels", "base_resolution", "log2_table_size", "feature_dim", "pe_bands",
                 "width", "depth", "normal_levels", "normal_log2_table_size"):
        if getattr(args, name, None) is not None:
            limits.check_range(f"--{name.replace('_', '-')}", getattr(args, name),
                               *BOUNDS[name.removeprefix("normal_")])
    low, high = BOUNDS["growth"]
    if args.growth is not None and not (math.isfinite(args.growth)
                                        and low <= args.growth <= high):
        raise VDNIFError(f"--growth {args.growth} must be a number in {low:g}..{high:g}")
    if args.pe_form is not None and args.pe_form not in PE_SCALES:
        raise VDNIFError(f"--pe-form '{args.pe_form}' must be one of "
                         f"{', '.join(map(repr, PE_SCALES))}")
    for option, choices in (("albedo_mode", ALBEDO_MODES), ("normal_mode", NORMAL_MODES)):
        if getattr(args, option) is not None and getattr(args, option) not in choices:
            raise VDNIFError(f"--{option.replace('_', '-')} '{getattr(args, option)}' must be "
                             f"one of {', '.join(map(repr, choices))}")
