"""The pipeline's batch commands: capture, dataset, references, train, and the commands on
the trained model (``model_commands``: render, evaluate); one function per command and the
parsers that name them (``add_commands``)."""

import pathlib
import sys

from .. import declarations as declared
from ..errors import VDNIFError
from ..output_rule import note_input
from ..safe_io import check_output_file, file_stem
from ..text import metrics_line, percent, value
from . import model_commands
from .options import (
    add_capture_options,
    add_image_options,
    add_network_options,
    add_pose_set_option,
    add_scene_options,
    add_secondary_options,
    add_setting,
    add_stress_options,
    add_training_options,
    asked_pose_set,
    load_posed_scene,
    names_scene,
    network_overrides,
    report_training,
    secondary_settings,
    with_suggestion,
    write_json,
)
from .outputs import output_file, output_folder, output_model


def cmd_capture(args):
    """Capture a scene: rest mesh, voxels, deformed corners per pose."""
    from ..blender.capture_scene import capture, check_corners_memory
    from ..blender.steps import training_follow
    from ..progress import Progress

    obj, spec = load_posed_scene(args)
    planned = capture(obj, args.resolution, spec, deform_corners=False)   # grid and poses
    if planned.mode != "static":        # refused before the choice is measured, not after
        check_corners_memory(obj, args.resolution, len(planned.poses),
                             len(planned.grid.corners))
    # the corners follow as a training of these poses would have them follow
    follow = training_follow(obj, args.resolution, spec, say=_say(f"capture '{obj.name}'"))
    progress = Progress(f"capture '{obj.name}'", spec.count, "poses")
    result = capture(obj, args.resolution, spec, progress=lambda done, _: progress.update(done),
                     follow=follow)
    summary = result.summary()
    summary["pose_source"] = "static" if result.mode == "static" else spec.source
    write_json(args.json, with_suggestion(args, summary))
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
    import tempfile

    from ..blender.steps import training_capture
    from ..blender.ui_jobs import SHARD_SUFFIXES
    from ..memory import check_disk
    from ..posed.estimate import dataset_estimate, describe, measure, size_text
    from ..posed.generate import generate_dataset
    from ..progress import Progress
    from ..training.dataset import (
        DatasetIdentity,
        check_folder,
        check_shard_size,
        grid_header,
        shard_name,
    )

    if args.rays_per_pose < 1:
        raise VDNIFError(f"rays per pose {args.rays_per_pose} must be at least 1")
    obj, spec = load_posed_scene(args)
    result = training_capture(obj, args.resolution, spec, say=_say(f"dataset '{obj.name}'"))
    pose_range = parse_range(args.pose_range, len(result.poses))
    check_folder(args.out, DatasetIdentity(result.mesh.name, args.seed,        # before work
                                           grid_header(result.grid)))
    mix = dict(surface_fraction=args.surface_fraction, grazing_fraction=args.grazing_fraction,
               secondary_fraction=args.secondary_fraction)
    try:
        with tempfile.TemporaryDirectory(prefix="vdnif-sample-") as scratch:
            rates = measure(obj, result, None, None, pathlib.Path(scratch) / "sample",
                            args.seed, args.rays_per_pose, **mix)
    except (OSError, VDNIFError) as exc:
        # The sample's own files are not the user's: a failed write names the temporary
        # folder (a full /tmp), not a shard that looks like one of --out's.
        cause = exc if isinstance(exc, OSError) else exc.__cause__
        if not isinstance(cause, OSError):
            raise
        reason = (cause.strerror or str(cause)).lower()
        raise VDNIFError(f"the temporary folder '{tempfile.gettempdir()}' cannot hold the "
                         f"sample that estimates the dataset ({reason}): free space there "
                         "or name another with TMPDIR; nothing was written to --out") from None
    expected = dataset_estimate(rates, pose_range[1] - pose_range[0], args.rays_per_pose)
    print(f"dataset '{obj.name}': {describe(expected)} (estimated from a sample)",
          file=sys.stderr, flush=True)
    check_shard_size(shard_name(*pose_range), expected["segments"])
    check_disk(f"dataset shard '{shard_name(*pose_range)}'", expected["bytes"], args.out,
               "lower --rays-per-pose or --poses, or free space")
    progress = Progress(f"dataset '{obj.name}'", pose_range[1] - pose_range[0], "poses")
    header = generate_dataset(obj, result, args.out, args.rays_per_pose, seed=args.seed,
                              pose_range=pose_range,
                              progress=lambda done, _: progress.update(done), **mix)
    size = sum((pathlib.Path(args.out) / f"{shard_name(*pose_range)}{suffix}").stat().st_size
               for suffix in SHARD_SUFFIXES)
    counts, timings = header.counts, header.timings
    walk_and_truth = timings["walk_s"] + timings["ground_truth_s"]
    print(f"dataset '{header.object}' poses {pose_range[0]}:{pose_range[1]} -> {args.out}")
    print(f"  rays {counts.rays}, segments {counts.segments}, hits {counts.hits}")
    print(f"  on disk {size_text(size)} ({size:,} bytes; estimated "
          f"{size_text(expected['bytes'])})")
    print(f"  {counts.segments / walk_and_truth:,.0f} segments/s, "
          f"{counts.rays / walk_and_truth:,.0f} rays/s of walk + ground truth; walk "
          f"{timings['walk_s']:.2f} s (kernel, entry BVH included), ground truth "
          f"{timings['ground_truth_s']:.2f} s")
    print(f"  also: pose preparation {timings['prepare_s']:.2f} s, Blender evaluation "
          f"{timings['evaluate_s']:.2f} s, training rays {timings['rays_s']:.2f} s, rest BVH "
          f"{timings['rest_surface_s']:.2f} s, records {timings['records_s']:.2f} s, writing "
          f"{timings['write_s']:.2f} s")
    _truncation_warning(counts.truncated_rays or 0, counts.rays)
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
    from ..blender.steps import evaluation_poses, training_follow
    from ..inference.metrics import check_compared
    from ..posed.generate import reference_run
    from ..progress import Progress

    obj, spec = load_posed_scene(args)
    # the embedding a model trained on the poses of spec would have: its corners' way
    follow = training_follow(obj, args.resolution, spec, say=_say(f"references '{obj.name}'"))
    result = evaluation_poses(obj, args.resolution, spec, follow=follow,
                              pose_set=args.pose_set)
    progress = Progress(f"references '{obj.name}'", len(result.poses), "poses")
    report = reference_run(obj, result, args.width, args.height, rest_pose=args.rest_pose,
                           progress=lambda done, _: progress.update(done),
                           secondary=secondary_settings(args, obj))
    check_compared(report["embedded_vs_true"], obj.name)
    report["pose_set"] = asked_pose_set(args)
    write_json(args.json, with_suggestion(args, report))
    error = report["embedded_vs_true"]
    print(f"references '{report['object']}' R={report['resolution']}, {report['poses']} "
          f"{'rest' if args.rest_pose else 'unseen'} poses, {args.width}x{args.height}")
    print(f"  embedded vs true: {metrics_line(error)}")
    if "secondary" in report:
        print(f"  secondary rays ({report['secondary']['light']}): AO MAE "
              f"{value(error['ao_mae'])}, shadow false lit "
              f"{percent(error['shadow_false_lit_rate'])}, false shadow "
              f"{percent(error['shadow_false_shadow_rate'])}")
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


def cmd_train(args):
    """Train a network on a dataset folder (or on a scene, generating its dataset first)
    and write the model file."""
    # Each import where it is used: a missing or broken --data is refused before Blender
    # and Warp load.
    if names_scene(args):
        result, summary = _train_on_scene(args)
    else:
        from ..training.dataset import read_dataset

        # the header alone: fit_model reads and checks the rows
        header = read_dataset(args.data, defer_row_check=True)[0].header
        variant = _variant(args, header.object, header.mode == "static")
        out = args.out or pathlib.Path(args.data) / f"{variant}.vdnif"
        check_output_file(out, "model file", "model")   # before training, not after it
        from ..training.fit import fit_model

        result, summary = fit_model(args.data, variant, out, network_overrides(args),
                                    progress=report_training,
                                    group_timeout_s=args.group_timeout)
    if not result.is_main:
        return 0
    from ..blender.steps import write_training_plot

    model = pathlib.Path(summary["model"])
    summary["plot"] = str(write_training_plot(model.with_name(f"{model.stem}-training.png"),
                                              summary["history"]))
    write_json(args.json, with_suggestion(args, summary))
    print(f"trained {summary['variant']} on '{summary['object']}' ({summary['segments']} "
          f"segments): "
          f"{result.status} after {result.steps} steps in {result.seconds:.1f} s, "
          f"{result.samples_per_s:,.0f} samples/s")
    if result.validation:
        print("  validation on held-out poses: " + ", ".join(
            f"{k} {v:.4g}" for k, v in result.validation.items()))
    print(f"  model {summary['model']} ({summary['model_bytes']:,} bytes), loss plot "
          f"{summary['plot']}")
    return 0


def _variant(args, name, static):
    """The variant to train on object ``name``: --variant, or the scene's own (static or
    deforming, ``variants.choose_variant``); what was decided is said on stderr."""
    from ..model.variants import choose_variant

    variant, note = choose_variant(args.variant, static)
    if note is not None:
        print(f"train: '{name}': {note}", file=sys.stderr)
    return variant


def _train_on_scene(args):
    """Capture, dataset (into --data, or a temporary folder) and training in one go."""
    import tempfile

    from ..blender.steps import train_variant, training_capture

    if args.data is not None and any(pathlib.Path(args.data).glob("*.json")):
        raise VDNIFError(f"dataset folder '{args.data}' already holds shards: give an empty "
                         "folder with scene options, or train on it with --data alone")
    def refuse_replacing_kept(obj):
        kept = _kept_model(obj)
        if kept is not None:        # replacing it asks for --force (safe_io's output rule)
            note_input(kept, f"the model that '{obj.name}' keeps in its .blend, which")
            if args.out is not None:
                check_output_file(args.out, "--out", "model")

    obj, spec = load_posed_scene(args, check=refuse_replacing_kept)
    captured = training_capture(obj, args.resolution, spec, say=_say(f"train '{obj.name}'"))
    variant = _variant(args, obj.name, captured.mode == "static")
    out = args.out or pathlib.Path("out") / f"{file_stem(obj.name.lower())}-{variant}.vdnif"
    check_output_file(out, "--out", "model")
    pathlib.Path(out).parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="vdnif-data-") as scratch:
        folder = args.data or pathlib.Path(scratch)
        print(f"dataset '{obj.name}': {len(captured.poses)} poses, {args.rays_per_pose} "
              f"rays per pose -> {args.data or 'a temporary folder'}", file=sys.stderr)
        return train_variant(obj, captured, variant, folder, args.rays_per_pose, out,
                             network_overrides(args), args.seed, progress=report_training)


def _say(subject):
    """A line's printer to stderr, beginning with ``subject``."""
    return lambda line: print(f"{subject}: {line}", file=sys.stderr, flush=True)


def _kept_model(obj):
    """The model file that the VDNIF settings of ``obj`` keep beside its .blend (loaded or
    trained in the panel, file storage), or None."""
    import bpy

    settings = obj.get("vdnif")
    text = settings.get("model_path") if hasattr(settings, "get") else None
    if not isinstance(text, str) or not text:
        return None
    path = pathlib.Path(bpy.path.abspath(text, library=obj.library))
    return path if path.is_file() else None


def _scene_command(commands, name, run, notes):
    """A command that reads a scene: scene, resolution, pose and stress options."""
    parser = commands.add_parser(name, help=run.__doc__, description=f"{run.__doc__} {notes}")
    add_scene_options(parser)
    add_capture_options(parser, name)
    add_stress_options(parser)
    parser.set_defaults(run=run)
    return parser


def add_commands(commands):
    """Adds the pipeline's commands to the batch parser's subcommands ``commands``."""
    capture = _scene_command(commands, "capture", cmd_capture, (
        "Writes --json with grid_dims, voxel_size, occupied_voxels, corners, poses, "
        "inverted_cells (per pose), heads and capture_s."))
    capture.add_argument("--json", type=output_file, metavar="PATH",
                         help="write the summary as JSON")

    data = _scene_command(commands, "dataset", cmd_dataset, (
        "Several processes may each write the shard of their --pose-range into one folder; "
        "training reads them all."))
    for setting in (declared.RAYS_PER_POSE, declared.SURFACE_FRACTION,
                    declared.GRAZING_FRACTION, declared.SECONDARY_FRACTION):
        add_setting(data, setting, "dataset")
    data.add_argument("--pose-range", metavar="A:B",
                      help="only poses A..B-1 of the N (default: all poses)")
    data.add_argument("--out", type=output_folder, required=True, metavar="DIR",
                      help="dataset folder (shards are added to it)")

    refs = _scene_command(commands, "references", cmd_references, (
        "Writes --json with embedded_vs_true (distance_mae in object units, "
        "normal_error_deg, hit_iou), rays_per_s and segments_per_s."))
    refs.add_argument("--rest-pose", action="store_true", help="use the undeformed pose")
    add_pose_set_option(refs)
    add_image_options(refs, "references")
    refs.add_argument("--json", type=output_file, metavar="PATH", help="write the report")
    add_secondary_options(refs, "references")

    training = commands.add_parser("train", help=cmd_train.__doc__, description=(
        cmd_train.__doc__ + " Under torchrun, each process trains on its share of the shards "
        "(DistributedDataParallel) and the first one writes the model and its loss plot "
        "(<model>-training.png beside it)."))
    training.add_argument("--data", type=output_folder, metavar="DIR", help=(
        "dataset folder written by 'dataset'; with scene options the dataset is generated "
        "into it first (default with scene options: a temporary folder)"))
    add_scene_options(training)
    add_capture_options(training, "train")
    add_stress_options(training)
    add_setting(training, declared.RAYS_PER_POSE, "train",
                help=f"with scene options: {declared.RAYS_PER_POSE.help}")
    add_setting(training, declared.VARIANT, "train")
    training.add_argument("--out", type=output_model, metavar="MODEL", help=(
        "model file (default DIR/<variant>.vdnif, or out/<object>-<variant>.vdnif)"))
    training.add_argument("--force", action="store_true", help=(
        "replace --out even when it is the model the --blend object keeps"))
    add_training_options(training)
    training.add_argument("--json", type=output_file, metavar="PATH", help=(
        "write the summary with the training history (step, task losses, validation)"))
    add_network_options(training)
    training.set_defaults(run=cmd_train)
    model_commands.add_commands(commands)
