"""The batch commands behind ``batch.py``: argument parsing and one function per command.

Each command prints its summary to stdout, progress to stderr, and a failure as one line
``vdnif: error: ...`` with a non-zero exit code.
"""

import argparse
import math
import os
import pathlib
import sys
import traceback

from .errors import VDNIFError
from .settings import DEMO_SCENE, EMBEDDING_ERROR_SHARE, RECIPE

AUTO_RESOLUTION = "auto"


class _DefaultsFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to every option that has a default its help does not state
    already; flags and options whose default is None (computed later) say it in words."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (action.option_strings and default not in (None, False, argparse.SUPPRESS)
                and "default" not in text):
            text += f" (default: {show_default(default)})"
        return text


def show_default(value):
    """A default as --help shows it: 45.0 as 45, ["bunny", "million"] as bunny million."""
    if isinstance(value, (list, tuple)):
        return " ".join(map(show_default, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage mistake on one line, like every other failure, and shows
    every option's default in --help."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _DefaultsFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        raise _UsageError(f"{self.prog}: {message} (see --help)")


class _UsageError(Exception):
    pass


def add_scene_options(parser):
    """``--scene NAME | --mesh FILE --rig R | --blend FILE --object NAME``."""
    from .blender.scenes import DEMO_SCENES, RIGS

    group = parser.add_argument_group("scene (one of)")
    source = group.add_mutually_exclusive_group()
    source.add_argument("--scene", choices=DEMO_SCENES,
                        help="an embedded demo scene (default: arm)")
    source.add_argument("--mesh", type=pathlib.Path, metavar="FILE",
                        help="an OBJ, PLY or glTF file, rigged procedurally (see --rig)")
    source.add_argument("--blend", type=pathlib.Path, metavar="FILE",
                        help="a .blend file; the object is --object or the active one")
    group.add_argument("--rig", choices=RIGS,
                       help="procedural rig for --mesh (default armature) or a demo scene")
    group.add_argument("--object", metavar="NAME", help="the mesh object in --blend")


def load_scene(args):
    """Builds or opens the scene the options name and returns the mesh object."""
    from .blender import scenes

    if args.mesh is not None:
        return scenes.mesh_scene(args.mesh, args.rig or "armature")
    if args.blend is not None:
        return scenes.blend_scene(args.blend, args.object)
    return scenes.demo_scene(args.scene or "arm", rig=args.rig)


def load_posed_scene(args):
    """(mesh object, PoseSpec): the scene of the options with ``--scale`` applied and
    ``--deform`` carried by the pose spec."""
    from .blender.extremes import apply_stress

    obj = load_scene(args)
    spec = apply_stress(args, obj, pose_spec(args))
    if getattr(args, "resolution", None) == AUTO_RESOLUTION:
        args.resolution = suggested_resolution(obj, spec)
    return obj, spec


def suggested_resolution(obj, spec):
    """``--resolution auto``: the suggested resolution of the scene (``blender/resolution``),
    with the embedding errors that decided it on stderr."""
    from .blender.resolution import network_error, suggest_resolution
    from .settings import SUGGEST_PRESET

    target = EMBEDDING_ERROR_SHARE * network_error()
    resolution, table = suggest_resolution(obj, spec, target)
    tried = ", ".join(f"R {row['resolution']}: {row['embedding_error']:.4g}" for row in table)
    print(f"resolution auto for '{obj.name}': {resolution} (embedding error {tried}; target "
          f"{target:.4g} object units = {EMBEDDING_ERROR_SHARE:g} x preset "
          f"{SUGGEST_PRESET}'s network error)", file=sys.stderr)
    return resolution


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
    group.add_argument("--pose-source", choices=("random", "frames"), default="random",
                       help="random bone rotations / lattice offsets, or timeline frames")
    group.add_argument("--seed", type=int, default=0, help="random pose seed (default 0)")
    group.add_argument("--max-angle", type=float, default=45.0, metavar="DEG",
                       help="largest random bone rotation per axis where the bone has no "
                            "rotation limits (default 45)")


def pose_spec(args):
    from .blender.poses import PoseSpec

    return PoseSpec(source=args.pose_source, count=args.poses, seed=args.seed,
                    max_angle_deg=args.max_angle)


def write_json(path, data):
    """Writes ``data`` as strict JSON to ``path`` atomically (``safe_io``: no half-written
    file, no write through a symlink, no NaN)."""
    from .safe_io import write_json_atomic

    if path is not None:
        write_json_atomic(path, data)


def check_resolution(value):
    from .voxels import MAX_RESOLUTION, MIN_RESOLUTION

    if value == AUTO_RESOLUTION:        # resolved once the scene is loaded
        return
    if not MIN_RESOLUTION <= value <= MAX_RESOLUTION:
        raise VDNIFError(f"resolution {value} is outside {MIN_RESOLUTION}..{MAX_RESOLUTION}")


def cmd_capture(args):
    """Capture a scene: rest mesh, voxels, deformed corners per pose."""
    from .blender.capture import capture
    from .progress import Progress

    check_resolution(args.resolution)
    obj, spec = load_posed_scene(args)
    progress = Progress(f"capture '{obj.name}'", spec.count, "poses")
    result = capture(obj, args.resolution, spec, progress=lambda done, _: progress.update(done))
    summary = result.summary()
    summary["pose_source"] = "static" if result.mode == "static" else spec.source
    write_json(args.json, summary)
    inverted = summary["inverted_cells"]
    print(f"captured '{summary['object']}' ({summary['mode']}"
          + (": no deform modifier, one pose" if result.mode == "static" else "") + ")")
    print(f"  triangles {summary['triangles']}, object size {summary['object_size']:.4g}")
    print(f"  grid {'x'.join(map(str, summary['grid_dims']))}, voxel size "
          f"{summary['voxel_size']:.4g}, occupied voxels {summary['occupied_voxels']}, "
          f"corners {summary['corners']}")
    print(f"  poses {summary['poses']}, inverted cells per pose: max {max(inverted)}, "
          f"total {sum(inverted)}")
    print(f"  heads {', '.join(k for k, v in summary['heads'].items() if v is True)}"
          f", materials {summary['heads']['material_count']}")
    for warning in summary["warnings"]:
        print(f"  warning: {warning}")
    print(f"  capture {summary['capture_s']:.2f} s")
    return 0


def cmd_dataset(args):
    """Generate a training dataset shard: walked segments with their ground truth."""
    from .blender.capture import capture
    from .blender.generate import generate_dataset
    from .dataset import check_folder, grid_header
    from .progress import Progress

    check_resolution(args.resolution)
    if args.rays_per_pose < 1:
        raise VDNIFError(f"rays per pose {args.rays_per_pose} must be at least 1")
    obj, spec = load_posed_scene(args)
    result = capture(obj, args.resolution, spec, deform_corners=False)
    pose_range = parse_range(args.pose_range, len(result.poses))
    check_folder(args.out, {"object": result.mesh.name, "seed": args.seed,      # before work
                            "grid": grid_header(result.grid)})
    progress = Progress(f"dataset '{obj.name}'", pose_range[1] - pose_range[0], "poses")
    header = generate_dataset(obj, result, args.out, args.rays_per_pose,
                              args.surface_fraction, args.seed, pose_range,
                              progress=lambda done, _: progress.update(done),
                              grazing_fraction=args.grazing_fraction)
    counts, timings = header["counts"], header["timings"]
    walk_and_truth = timings["walk_s"] + timings["ground_truth_s"]
    print(f"dataset '{header['object']}' poses {pose_range[0]}:{pose_range[1]} -> {args.out}")
    print(f"  rays {counts['rays']}, segments {counts['segments']}, hits {counts['hits']}")
    print(f"  {counts['segments'] / walk_and_truth:,.0f} segments/s, "
          f"{counts['rays'] / walk_and_truth:,.0f} rays/s of walk + ground truth; walk "
          f"{timings['walk_s']:.2f} s (kernel, entry BVH included), ground truth "
          f"{timings['ground_truth_s']:.2f} s")
    print(f"  also: pose preparation {timings['prepare_s']:.2f} s, Blender evaluation "
          f"{timings['evaluate_s']:.2f} s, training rays {timings['rays_s']:.2f} s, rest BVH "
          f"{timings['rest_surface_s']:.2f} s, records {timings['records_s']:.2f} s, writing "
          f"{timings['write_s']:.2f} s")
    _truncation_warning(counts.get("truncated_rays", 0), counts["rays"])
    return 0


def parse_range(text, count):
    """``A:B`` -> (A, B) within 0..count; None -> the whole range."""
    if text is None:
        return 0, count
    try:
        start, stop = (int(part) for part in text.split(":"))
    except ValueError:
        raise VDNIFError(f"pose range '{text}' is not of the form A:B") from None
    if not 0 <= start < stop <= count:
        raise VDNIFError(f"pose range {start}:{stop} is outside 0:{count}")
    return start, stop


def cmd_references(args):
    """Render the true and embedded references on unseen poses; report the embedding error."""
    from .blender.capture import capture
    from .blender.generate import reference_run
    from .blender.poses import evaluation_spec
    from .progress import Progress

    check_resolution(args.resolution)
    obj, spec = load_posed_scene(args)
    result = capture(obj, args.resolution, evaluation_spec(spec), deform_corners=False)
    progress = Progress(f"references '{obj.name}'", len(result.poses), "poses")
    report = reference_run(obj, result, args.width, args.height, rest_pose=args.rest_pose,
                           progress=lambda done, _: progress.update(done))
    write_json(args.json, report)
    error = report["embedded_vs_true"]
    print(f"references '{report['object']}' R={report['resolution']}, {report['poses']} "
          f"{'rest' if args.rest_pose else 'unseen'} poses, {args.width}x{args.height}")
    print(f"  embedded vs true: {metrics_text(error)}")
    print(f"  {report['rays_per_s']:,.0f} rays/s, {report['segments_per_s']:,.0f} segments/s "
          "of walk + ground truth")
    print("  " + ", ".join(f"{name[:-2].replace('_', ' ')} {seconds:.2f} s"
                           for name, seconds in report["timings"].items()))
    _truncation_warning(report.get("truncated_rays", 0), report["poses"] * args.width
                        * args.height)
    return 0


def _truncation_warning(truncated, rays):
    """Says how many rays the walk's bounds (step budget, seek casts) stopped early."""
    if truncated:
        print(f"  warning: {truncated} of {rays} rays were stopped by the walk's step or "
              "seek bound (their later segments are missing)")


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
    losses = ", ".join(f"{k} {v:.4f}" for k, v in record["losses"].items())
    print(f"train: step {record['step']}/{record['steps']}, loss {record['total']:.4f} "
          f"({losses}), {record['samples_per_s']:,.0f} samples/s, "
          f"ETA {record['eta_s']:.0f} s", file=sys.stderr, flush=True)


def cmd_train(args):
    """Train a network on a dataset folder (or on a scene, generating its dataset first)
    and write the model file."""
    from .dataset import read_dataset
    from .fit import fit_model

    if _names_scene(args):
        result, summary = _train_on_scene(args)
    else:
        if args.data is None:
            raise VDNIFError("give --data DIR (a dataset folder) or scene options "
                             "(--scene, --mesh or --blend)")
        header, _ = read_dataset(args.data)
        variant = _variant(args, header["object"], header.get("mode") == "static")
        out = args.out or pathlib.Path(args.data) / f"{variant}.vdnif"
        result, summary = fit_model(args.data, variant, out, network_overrides(args),
                                    progress=report_training)
    if not result.is_main:
        return 0
    write_json(args.json, summary)
    print(f"trained {summary['variant']} on '{summary['object']}' ({summary['segments']} "
          f"segments): "
          f"{result.status} after {result.steps} steps in {result.seconds:.1f} s, "
          f"{result.samples_per_s:,.0f} samples/s")
    if result.validation:
        print("  validation on held-out poses: " + ", ".join(
            f"{k} {v:.4g}" for k, v in result.validation.items()))
    print(f"  model {summary['model']} ({summary['model_bytes']:,} bytes)")
    return 0


def _variant(args, name, static):
    """The variant to train on object ``name``: --variant, or the scene's own (static or
    deforming, ``variants.choose_variant``); what was decided is said on stderr."""
    from .variants import choose_variant

    variant, note = choose_variant(args.variant, static)
    if note is not None:
        print(f"train: '{name}': {note}", file=sys.stderr)
    return variant


def _names_scene(args):
    return any(getattr(args, name) is not None for name in ("scene", "mesh", "blend"))


def _train_on_scene(args):
    """Capture, dataset (into --data, or a temporary folder) and training in one go."""
    import tempfile

    from .blender.capture import capture
    from .blender.jobs import train_variant

    check_resolution(args.resolution)
    if args.data is not None and any(pathlib.Path(args.data).glob("*.json")):
        raise VDNIFError(f"dataset folder '{args.data}' already holds shards: give an empty "
                         "folder with scene options, or train on it with --data alone")
    obj, spec = load_posed_scene(args)
    captured = capture(obj, args.resolution, spec, deform_corners=False)
    variant = _variant(args, obj.name, captured.mode == "static")
    out = args.out or pathlib.Path("out") / f"{obj.name.lower()}-{variant}.vdnif"
    pathlib.Path(out).parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="vdnif-data-") as scratch:
        folder = args.data or pathlib.Path(scratch)
        print(f"dataset '{obj.name}': {len(captured.poses)} poses, {args.rays_per_pose} "
              f"rays per pose -> {args.data or 'a temporary folder'}", file=sys.stderr)
        return train_variant(obj, captured, variant, folder, args.rays_per_pose, out,
                             network_overrides(args), args.seed, progress=report_training)


def _read_model(args):
    """(network, metadata) of the --model file, read once per command, its metadata checked
    for what a scene needs (a complete grid, an integer resolution)."""
    from .model_file import check_scene_metadata, load_model

    loaded = load_model(args.model)
    check_scene_metadata(args.model, loaded[1]["extra"])
    return loaded


def _model_resolution(args, extra):
    """--resolution, or the model's own (``extra``: its metadata ``extra``) when not given
    (they must agree anyway)."""
    if args.resolution is not None:
        check_resolution(args.resolution)
        return args.resolution
    return int(extra["grid"]["resolution"])


def cmd_render(args):
    """Render the predicted passes of a pose through a camera with a trained model."""
    import bpy

    from .blender.capture import capture
    from .blender.jobs import write_passes
    from .blender.neural import camera_rays, load_scene_model, render_orbit, render_rays
    from .blender.scenes import find_camera

    loaded = _read_model(args)
    resolution = _model_resolution(args, loaded[1]["extra"])
    obj, spec = load_posed_scene(args)
    captured = capture(obj, resolution, spec, deform_corners=False)
    model = load_scene_model(args.model, captured, args.device, loaded)
    scene = bpy.context.scene
    frame = scene.frame_current if args.frame is None else args.frame
    pose = {"frame": float(frame)}
    camera = find_camera(args.camera)
    if camera is not None:
        origins, directions = camera_rays(camera, args.width, args.height)
        view = f"camera '{camera.name}'"
        result = render_rays(obj, captured, model, pose, origins, directions,
                             references=args.references)
    else:
        view = "an orbit viewpoint (the scene has no camera)"
        result = render_orbit(obj, captured, model, pose, args.width, args.height,
                              references=args.references)
    slots = captured.mesh.material_slots
    written = write_passes(args.out, result.predicted, args.height, args.width,
                           result.world_scale, slots=slots)
    if args.references:
        for name in ("true", "embedded"):
            written += write_passes(args.out, getattr(result, name), args.height, args.width,
                                    result.world_scale, prefix=f"{name}-", slots=slots)
    summary = {"model": str(args.model), "object": obj.name, "frame": frame, "view": view,
               "width": args.width, "height": args.height,
               "hit_pixels": int(result.predicted.hit.sum()), "timings": result.timings,
               "rays_per_s": result.timings["rays"] / result.timings["render_s"],
               "files": [str(path) for path in written]}
    write_json(pathlib.Path(args.out) / "render.json", summary)
    print(f"rendered '{obj.name}' at frame {frame:g} through {view}, {args.width}x"
          f"{args.height}: {summary['hit_pixels']} hit pixels, "
          f"{summary['rays_per_s']:,.0f} rays/s -> {args.out}")
    return 0


def cmd_evaluate(args):
    """Evaluate a trained model on unseen poses against the true and embedded references."""
    from .blender.jobs import evaluate_file, evaluation_poses, write_figures
    from .progress import Progress

    loaded = _read_model(args)
    resolution = _model_resolution(args, loaded[1]["extra"])
    trained = loaded[1]["extra"].get("train_poses", [])
    obj, spec = load_posed_scene(args)
    captured = evaluation_poses(obj, resolution, spec, rest=args.rest_pose, trained=trained)
    progress = Progress(f"evaluate '{obj.name}'", len(captured.poses), "poses")
    report, views = evaluate_file(obj, captured, args.model, args.width, args.height,
                                  args.device, lambda done, _: progress.update(done),
                                  loaded=loaded)
    if args.out is not None:
        report["figures"] = {name: str(path) for name, path in write_figures(
            args.out, views[0], args.height, args.width, captured.mesh.size).items()}
    write_json(args.json, report)
    print_evaluation(report)
    return 0


def print_evaluation(report):
    from .studies.report import speed_line

    print(f"evaluated {report['variant']} on '{report['object']}' R={report['resolution']}, "
          f"{report['poses']} {'unseen ' if report['unseen_poses'] else ''}poses, "
          f"{report['width']}x{report['height']}")
    for name in ("vs_true", "vs_embedded"):
        print(f"  {name.replace('_', ' ')}: {metrics_text(report[name])}")
    t = report["timings"]
    print(f"  pose preparation {t['prepare_pose_s'] * 1e3:.1f} ms, model "
          f"{report['model_bytes']:,} bytes, render {speed_line(report)}")


def metrics_text(m):
    """One line of compare's metrics: distance error in object units and voxels, normal
    error, the hit-mask metrics and the scene's optional metrics (n/a where the scene has
    nothing to predict: one material without texture)."""
    from .text import percent

    voxels = m.get("distance_mae_voxels")
    extra = "".join(f", {name} {_number(m.get(key))}" for key, name in (
        ("albedo_psnr", "albedo PSNR"), ("material_accuracy", "material accuracy")))
    return (f"distance MAE {_number(m['distance_mae'])} object units"
            + ("" if voxels is None else f" ({_number(voxels)} voxels)")
            + f", normal error {_number(m['normal_error_deg'])} deg, hit IoU "
            f"{_number(m['hit_iou'])}, false negatives {percent(m.get('false_negative_rate'))}"
            f", false positives {percent(m.get('false_positive_rate'))}{extra}")


def _number(value):
    return "n/a" if value is None else f"{value:.4g}"


def cmd_demo(args):
    """The main job on an embedded scene: capture, dataset, train (proposed), render and
    evaluate on unseen poses, and a short report with the figure."""
    from .studies.demo import run_demo
    from .blender.extremes import apply_stress

    report = run_demo(args.scene, args.out, quick=args.quick, device=args.device,
                      steps=args.steps, progress=report_training,
                      stress=lambda obj, spec: apply_stress(args, obj, spec))
    write_json(args.json, report)
    print_evaluation(report)
    print(f"  report {report['report']}")
    return 0


def cmd_experiment(args):
    """Run one of the paper's experiments and write its section of the results file."""
    from .studies.experiments import run_experiment

    scenes = args.scenes.split(",") if args.scenes else None
    records = run_experiment(args.name, args.results, quick=args.quick, device=args.device,
                             progress=report_training, scenes=scenes, seeds=args.seeds)
    for label, report in records.items():
        m = report.get("common", report)     # the table's figures: the common pixel set
        print(f"{label}: vs true distance MAE {_number(m['vs_true']['distance_mae'])} "
              f"({_number(m['vs_true'].get('distance_mae_voxels'))} voxels), normal error "
              f"{_number(m['vs_true']['normal_error_deg'])} deg, hit IoU "
              f"{_number(m['vs_true']['hit_iou'])}; vs embedded "
              f"{_number(m['vs_embedded']['distance_mae'])}, "
              f"{_number(m['vs_embedded']['normal_error_deg'])} deg")
    print(f"  written to {args.results}")
    return 0


def cmd_bench(args):
    """Sweep resolution, hash grid, PE bands, width and steps; derive the presets."""
    from .studies.bench import NO_PRESETS, run_bench
    from .presets import PRESETS_FILE

    quick_dir = pathlib.Path("out/bench-quick")
    out = args.out or (quick_dir if args.quick else pathlib.Path("docs/bench"))
    presets = args.presets or (quick_dir / "presets.json" if args.quick else PRESETS_FILE)
    performance = args.performance or (None if args.quick else pathlib.Path(
        "docs/performance.md"))
    rows, derived = run_bench(out, presets, performance, quick=args.quick,
                              device=args.device, progress=report_training)
    print(f"bench: {len(rows)} points -> {out}/bench.csv, bench.json, pareto.png; presets "
          + (f"-> {presets}" if derived is not None else f"n/a ({NO_PRESETS}; {presets} "
             "left as it was)")
          + (f"; section of {performance}" if performance else ""))
    return 0


def cmd_bench_network(args):
    """Measure encoder+MLP inference segments/s and training samples/s (paper setting)."""
    from .studies.network_bench import benchmark_network

    result = benchmark_network(device=args.device, repeats=args.repeats)
    write_json(args.json, result)
    print(f"network ({result['device']}, {result['threads']} torch threads): "
          f"{result['infer_segments_per_s']:,.0f} segments/s inference "
          f"({result['serial_segments_per_s']:,.0f} with the encoder and the MLP one after "
          f"the other: encoder {result['encode_fraction']:.0%}, MLP {result['mlp_fraction']:.0%}"
          f"), {result['train_samples_per_s']:,.0f} samples/s training")
    return 0


def add_capture_options(parser, default_poses):
    parser.add_argument("--resolution", type=resolution_option, default=RECIPE.resolution,
                        metavar="R", help=f"voxels along the longest side, 4..256, or "
                        f"'{AUTO_RESOLUTION}': the coarsest whose voxel embedding error is "
                        f"at most {EMBEDDING_ERROR_SHARE:g} x the network's (default "
                        f"{RECIPE.resolution})")
    add_pose_options(parser, default_poses)


def _scene_command(commands, name, run, default_poses, notes):
    """A command that reads a scene: scene, resolution, pose and stress options."""
    from .blender.extremes import add_stress_options

    parser = commands.add_parser(name, help=run.__doc__, description=f"{run.__doc__} {notes}")
    add_scene_options(parser)
    add_capture_options(parser, default_poses)
    add_stress_options(parser)
    parser.set_defaults(run=run)
    return parser


def add_device_option(parser, default="auto"):
    """``--device auto|cpu|cuda`` (train.DEVICES, named here so that parsing never imports
    torch): auto takes CUDA where torch has it."""
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default=default,
                        help=f"where the network runs (default {default})")


def add_training_options(parser):
    parser.add_argument("--steps", type=int, default=RECIPE.steps, metavar="N",
                        help=f"optimizer steps (default {RECIPE.steps})")
    parser.add_argument("--batch", type=int, default=RECIPE.batch_size, metavar="B",
                        help=f"segments per step and process (default {RECIPE.batch_size})")
    add_device_option(parser)


def _model_command(commands, name, run, default_poses, notes):
    """A command that uses a trained model on a scene; the resolution is the model's."""
    from .blender.extremes import add_stress_options

    parser = commands.add_parser(name, help=run.__doc__, description=f"{run.__doc__} {notes}")
    parser.add_argument("--model", type=pathlib.Path, required=True, metavar="MODEL",
                        help="a model file written by 'train' or 'demo'")
    add_scene_options(parser)
    parser.add_argument("--resolution", type=int, metavar="R",
                        help="voxel resolution (default: the model's; must match it)")
    add_pose_options(parser, default_poses)
    add_stress_options(parser)
    parser.add_argument("--width", type=int, default=128, metavar="W")
    parser.add_argument("--height", type=int, default=128, metavar="H")
    add_device_option(parser)
    parser.set_defaults(run=run)
    return parser


def build_parser():
    from .blender.extremes import add_stress_options
    from .studies.side_by_side_command import add_side_by_side_parser
    from .blender.scenes import DEMO_SCENES

    parser = _Parser(prog="batch.py", description=(
        "VDNIF batch commands. Run as: blender --background --python vdnif_addon/batch.py "
        "-- <command> [options], or python vdnif_addon/batch.py -- <command> [options]."))
    parser.add_argument("--debug", action="store_true", help=(
        f"show the traceback of a failure (anywhere on the line; or {DEBUG_ENV}=1)"))
    commands = parser.add_subparsers(dest="command", metavar="<command>", parser_class=_Parser)
    capture = _scene_command(commands, "capture", cmd_capture, 8, (
        "Writes --json with grid_dims, voxel_size, occupied_voxels, corners, poses, "
        "inverted_cells (per pose), heads and capture_s."))
    capture.add_argument("--json", type=pathlib.Path, metavar="PATH",
                         help="write the summary as JSON")

    data = _scene_command(commands, "dataset", cmd_dataset, RECIPE.poses, (
        "Several processes may each write the shard of their --pose-range into one folder; "
        "training reads them all."))
    data.add_argument("--rays-per-pose", type=int, default=RECIPE.rays_per_pose, metavar="K",
                      help=f"training rays per pose (default {RECIPE.rays_per_pose})")
    data.add_argument("--surface-fraction", type=float, default=RECIPE.surface_fraction,
                      metavar="F", help="share of rays aimed from outside at a surface point "
                      f"(default {RECIPE.surface_fraction})")
    data.add_argument("--grazing-fraction", type=float, default=RECIPE.grazing_fraction,
                      metavar="F", help="share of rays tangent to the surface at a surface "
                      "point (silhouette rays); the rest aim at random points in the bounds "
                      f"(default {RECIPE.grazing_fraction})")
    data.add_argument("--pose-range", metavar="A:B", help="only poses A..B-1 of the N")
    data.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR",
                      help="dataset folder (shards are added to it)")

    refs = _scene_command(commands, "references", cmd_references, 4, (
        "Writes --json with embedded_vs_true (distance_mae in object units, "
        "normal_error_deg, hit_iou), rays_per_s and segments_per_s."))
    refs.add_argument("--rest-pose", action="store_true", help="use the undeformed pose")
    refs.add_argument("--width", type=int, default=128, metavar="W")
    refs.add_argument("--height", type=int, default=128, metavar="H")
    refs.add_argument("--json", type=pathlib.Path, metavar="PATH", help="write the report")

    training = commands.add_parser("train", help=cmd_train.__doc__, description=(
        cmd_train.__doc__ + " Under torchrun, each process trains on its share of the shards "
        "(DistributedDataParallel) and the first one writes the model."))
    training.add_argument("--data", type=pathlib.Path, metavar="DIR", help=(
        "dataset folder written by 'dataset'; with scene options the dataset is generated "
        "into it first (default then: a temporary folder)"))
    add_scene_options(training)
    add_capture_options(training, RECIPE.poses)
    add_stress_options(training)
    training.add_argument("--rays-per-pose", type=int, default=RECIPE.rays_per_pose,
                          metavar="K", help="with scene options: training rays per pose "
                          f"(default {RECIPE.rays_per_pose})")
    training.add_argument("--variant", choices=("lsnif", "deformed", "proposed"), help=(
        "default: lsnif for a scene that no armature or lattice deforms (static), else "
        "proposed"))
    training.add_argument("--out", type=pathlib.Path, metavar="MODEL", help=(
        "model file (default DIR/<variant>.vdnif, or out/<object>-<variant>.vdnif)"))
    add_training_options(training)
    training.add_argument("--json", type=pathlib.Path, metavar="PATH")
    group = training.add_argument_group("encoding and network (default: the variant's)")
    for option, (_, kind, text) in NETWORK_OPTIONS.items():
        group.add_argument(option, type=kind, help=text)
    training.set_defaults(run=cmd_train)

    render = _model_command(commands, "render", cmd_render, 1, (
        "Writes per pass (hit, distance, normal, albedo, material) a PNG for looking and an "
        "EXR for use (distance in world units) and render.json into --out."))
    render.add_argument("--frame", type=float, metavar="F",
                        help="the timeline frame to pose the scene at (default: current)")
    render.add_argument("--camera", metavar="NAME", help=(
        "camera object (default: the scene's camera, else an orbit viewpoint)"))
    render.add_argument("--references", action="store_true",
                        help="also render the true and embedded references")
    render.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR")

    evaluate = _model_command(commands, "evaluate", cmd_evaluate, 8, (
        "Poses are the evaluation poses of --seed: another random seed or frames between "
        "the training frames, never trained on. Writes --json with variant, config, vs_true "
        "and vs_embedded (distance_mae in object units, normal_error_deg, hit_iou, "
        "albedo_psnr, material_accuracy), timings and model_bytes."))
    evaluate.add_argument("--rest-pose", action="store_true",
                          help="evaluate on views of the undeformed rest pose instead")
    evaluate.add_argument("--out", type=pathlib.Path, metavar="DIR",
                          help="write the comparison figures and error images here")
    evaluate.add_argument("--json", type=pathlib.Path, metavar="PATH")

    demo = commands.add_parser("demo", help=cmd_demo.__doc__, description=cmd_demo.__doc__)
    demo.add_argument("--scene", choices=DEMO_SCENES, default=DEMO_SCENE,
                      help=f"an embedded demo scene (default {DEMO_SCENE})")
    demo.add_argument("--quick", action="store_true", help="a small size, for tests")
    add_stress_options(demo)
    demo.add_argument("--steps", type=int, metavar="N", help="training steps (default: "
                      "the demo's own)")
    add_device_option(demo)
    demo.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/demo"),
                      metavar="DIR", help="default out/demo")
    demo.add_argument("--json", type=pathlib.Path, metavar="PATH",
                      help="also write the report JSON here (it is always in DIR)")
    demo.set_defaults(run=cmd_demo)

    experiment = commands.add_parser("experiment", help=cmd_experiment.__doc__,
                                     description=cmd_experiment.__doc__)
    experiment.add_argument("name", choices=("static", "deformation", "ablation", "per-pose"))
    experiment.add_argument("--quick", action="store_true", help="a tiny size, for tests")
    experiment.add_argument("--scenes", metavar="A,B", help="only these of the experiment's "
                            "scenes (default all; the section names them)")
    experiment.add_argument("--seeds", type=int, metavar="N", help="only the first N of the "
                            "size's seeds (default all: 3, or 2 with --quick)")
    add_device_option(experiment)
    experiment.add_argument("--results", type=pathlib.Path,
                            default=pathlib.Path("docs/results.md"), metavar="PATH",
                            help="markdown file whose section is rewritten (default "
                                 "docs/results.md; figures and JSON beside it in results/)")
    experiment.set_defaults(run=cmd_experiment)

    sweep = commands.add_parser("bench", help=cmd_bench.__doc__, description=(
        cmd_bench.__doc__ + " Each point trains the proposed variant on the arm and evaluates "
        "it on unseen poses (accuracy against both references, training time, render rays/s, "
        "model bytes)."))
    sweep.add_argument("--quick", action="store_true",
                       help="a small sweep (minutes) into out/bench-quick, presets not shipped")
    sweep.add_argument("--out", type=pathlib.Path, metavar="DIR",
                       help="bench.csv, bench.json, pareto.png (default docs/bench)")
    sweep.add_argument("--presets", type=pathlib.Path, metavar="PATH",
                       help="presets JSON (default: the one the panel reads)")
    sweep.add_argument("--performance", type=pathlib.Path, metavar="PATH",
                       help="markdown whose sweep section is rewritten "
                            "(default docs/performance.md; none with --quick)")
    add_device_option(sweep)
    sweep.set_defaults(run=cmd_bench)

    add_side_by_side_parser(commands)

    bench = commands.add_parser("bench-network", help=cmd_bench_network.__doc__,
                                description=cmd_bench_network.__doc__ + " JSON keys "
                                "infer_segments_per_s, serial_segments_per_s, "
                                "encode_segments_per_s, mlp_segments_per_s, encode_fraction, "
                                "mlp_fraction, train_samples_per_s, threads.")
    add_device_option(bench)
    bench.add_argument("--threads", type=int, metavar="N",
                       help="torch threads (default: the product's, vdnif_addon/threads.py)")
    bench.add_argument("--repeats", type=int, default=5)
    bench.add_argument("--json", type=pathlib.Path, metavar="PATH")
    bench.set_defaults(run=cmd_bench_network)
    return parser


OUTPUT_FILES = ("json", "markdown", "results", "presets", "performance")
"""Options naming a file a command writes; ``--out`` is a file for train, else a folder."""
IMAGE_COMMANDS = ("references", "render", "evaluate", "side-by-side")
"""Commands whose --width/--height are an image's (train's --width is the MLP's)."""


def validate_arguments(args):
    """Checks every option that can be wrong on its own, and every input and output place,
    before any work: the first problem raises VDNIFError (``limits`` holds the caps)."""
    from . import limits
    from .safe_io import check_output_file, check_output_folder

    def given(name):
        return getattr(args, name, None) is not None

    def at_least(name, low, high=None, label=None):
        if given(name):
            limits.check_range(label or f"--{name.replace('_', '-')}", getattr(args, name),
                               low, high)

    at_least("seed", 0, limits.MAX_SEED)
    at_least("poses", 1, limits.MAX_POSES)
    at_least("rays_per_pose", 1, limits.MAX_RAYS_PER_POSE, "rays per pose")
    at_least("repeats", 1)
    at_least("threads", 1)
    at_least("batch", 1, limits.MAX_BATCH)
    at_least("steps", 1)
    if isinstance(getattr(args, "resolution", None), int):
        check_resolution(args.resolution)
    for name, low, high in (("surface_fraction", 0.0, 1.0), ("max_angle", 0.0, 180.0)):
        value = getattr(args, name, None)
        if value is not None and not (math.isfinite(value) and low <= value <= high):
            raise VDNIFError(f"--{name.replace('_', '-')} {value} must be a number in "
                             f"{low:g}..{high:g}")
    if given("frame") and not math.isfinite(args.frame):
        raise VDNIFError(f"--frame {args.frame} is not a finite number")
    if args.command in IMAGE_COMMANDS and given("width") and given("height"):
        limits.check_image(args.width, args.height)
    if args.command == "train":
        _validate_network_options(args, limits)
    for name in OUTPUT_FILES:
        if given(name):
            check_output_file(getattr(args, name), f"--{name}")
    if args.command == "train" and given("data") and _names_scene(args):
        check_output_folder(args.data, "--data folder")
    if given("out"):
        if args.command == "train":
            check_output_file(args.out, "--out model file")
        else:
            check_output_folder(args.out, "--out folder")


def _validate_network_options(args, limits):
    for name, low, high in (("levels", 1, 64), ("base_resolution", 1, 1 << 20),
                            ("log2_table_size", 1, limits.MAX_LOG2_TABLE_SIZE),
                            ("feature_dim", 1, 64), ("pe_bands", 0, 32), ("width", 1, 4096),
                            ("depth", 0, 64)):
        if getattr(args, name, None) is not None:
            limits.check_range(f"--{name.replace('_', '-')}", getattr(args, name), low, high)
    if args.growth is not None and not (math.isfinite(args.growth) and 1 <= args.growth <= 16):
        raise VDNIFError(f"--growth {args.growth} must be a number in 1..16")
    if args.pe_form is not None and args.pe_form not in ("paper", "pi"):
        raise VDNIFError(f"--pe-form '{args.pe_form}' must be 'paper' or 'pi'")


DEBUG_ENV = "VDNIF_DEBUG"


def _debugging(argv):
    """(argv without ``--debug``, whether tracebacks are wanted: --debug or VDNIF_DEBUG=1)."""
    wanted = "--debug" in argv or os.environ.get(DEBUG_ENV, "") not in ("", "0")
    return [arg for arg in argv if arg != "--debug"], wanted


def main(argv):
    """Runs one batch command; returns the process exit code: 0, or 1 after one line
    ``vdnif: error: ...`` on stderr for any failure (the traceback only with --debug)."""
    argv, debug = _debugging(list(argv))
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 2
        validate_arguments(args)
        from .threads import use_threads

        use_threads(getattr(args, "threads", None))
        return args.run(args)
    except (_UsageError, VDNIFError) as exc:
        if debug:
            traceback.print_exc()
        print(f"vdnif: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("vdnif: error: interrupted", file=sys.stderr)
        return 1
    except (Exception, SystemExit) as exc:     # noqa: BLE001 - the last line of defence
        if isinstance(exc, SystemExit) and exc.code in (0, None):
            return 0                           # --help, --version
        if debug:
            traceback.print_exc()
        where = "" if debug else f"; run again with --debug (or {DEBUG_ENV}=1) for the traceback"
        print(f"vdnif: error: internal error (a bug in VDNIF, please report it): "
              f"{type(exc).__name__}: {_one_line(exc)}{where}", file=sys.stderr)
        return 1


def _one_line(exc):
    lines = str(exc).strip().splitlines()
    return " ".join(line.strip() for line in lines)[:500] if lines else type(exc).__name__
