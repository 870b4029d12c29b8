"""The batch commands on a trained model: render and evaluate. Each reads the --model file
once and captures the scene of the options again as the model was trained on it
(``steps.model_capture``)."""

import pathlib

from .. import declarations as declared
from ..inference.metrics import verdict
from ..pose_sets import TEST_POSES
from .options import (
    SHADED_HELP,
    add_image_options,
    add_pose_options,
    add_pose_set_option,
    add_scene_options,
    add_secondary_options,
    add_setting,
    add_stress_options,
    asked_pose_set,
    frames_option,
    load_posed_scene,
    print_evaluation,
    secondary_settings,
    write_json,
)
from .outputs import output_file, output_folder


def _model_scene(args, evaluation=False):
    """(network and metadata, mesh object, capture) of a command on the --model file: the
    model read once (``load_model`` checks it), the scene of the options captured again as
    the model was trained on it (``steps.model_capture``: at --resolution when given, else the
    model's; with ``evaluation`` on evaluation poses, or views of the rest pose)."""
    from ..blender.steps import model_capture
    from ..model.model_file import load_model

    loaded, asked = load_model(args.model), args.resolution
    obj, spec = load_posed_scene(args)
    captured = model_capture(obj, loaded[1], spec, evaluation, resolution=asked,
                             rest=getattr(args, "rest_pose", False),
                             pose_set=asked_pose_set(args) or TEST_POSES)
    args.resolution = captured.grid.resolution
    return loaded, obj, captured


def cmd_render(args):
    """Render the predicted passes of a pose, or of a range of frames, through a camera with a
    trained model."""
    import bpy

    from ..blender.pose_reader import PoseReader
    from ..blender.poses import posed
    from ..blender.scenes import find_camera
    from ..blender.steps import DistanceScale, write_view
    from ..kernels import runtime
    from ..memory import check_disk
    from ..output_rule import all_or_nothing, staged_size
    from ..posed.animation import frame_pose, render_frames
    from ..posed.render import camera_view, load_scene_model
    from ..progress import Progress

    loaded, obj, captured = _model_scene(args)
    model = load_scene_model(args.model, captured, args.device, loaded, args.precision)
    kernels_s = runtime.load_all(runtime.device(model.device))     # apart from the rays/s
    sequence = args.frames is not None
    frames = args.frames if sequence else [
        bpy.context.scene.frame_current if args.frame is None else args.frame]

    def light_at(frame):            # the AO and shadow settings, the light as in that frame
        with posed(frame_pose(frame)):
            return secondary_settings(args, obj)

    secondary = light_at if getattr(args, "secondary", False) else None
    camera = find_camera(args.camera)
    if camera is not None:
        camera_view(camera, args.width, args.height)    # refuses a non-camera before work
        view = f"camera '{camera.name}'"
    else:
        view = "an orbit viewpoint (the scene has no camera)"
    written, slots = [], captured.mesh.material_slots
    progress = Progress(f"render '{obj.name}'", len(frames), "frames")
    scale = DistanceScale()                 # one distance scale for every frame

    def write(frame, result):
        written.extend(write_view(args.out, result, args.height, args.width, slots,
                                  args.references, frame if sequence else None, scale=scale))
        if sequence and len(frames) > 1 and frame == frames[0]:   # the rest's disk, foretold
            size = staged_size(written)      # still temporaries: all_or_nothing below
            check_disk(f"rendering {len(frames):,} frames of {args.width}x{args.height}",
                       size * (len(frames) - 1), args.out,
                       "render a shorter --frames range, a larger step or smaller images")

    reader = PoseReader(obj, captured, None if camera is None else (
        lambda: camera_view(camera, args.width, args.height)))
    # Every file of the run (each frame's PNGs and EXR, render.json) is written to a
    # temporary and takes its name only once all are written: a failure leaves the old set.
    with all_or_nothing():
        try:
            figures = render_frames(reader, captured, model, frames, args.width, args.height,
                                    references=args.references, each=write,
                                    progress=(lambda done, _: progress.update(done))
                                    if sequence else None, secondary=secondary)
        finally:
            reader.close()
        summary = {"model": str(args.model), "object": obj.name, "view": view,
                   "width": args.width, "height": args.height, "kernels_s": kernels_s,
                   "distance_preview_range": scale.near_far,
                   "files": [str(path) for path in written]}
        if sequence:
            summary["frames"] = figures
        else:
            summary.update(figures[0])
        write_json(pathlib.Path(args.out) / "render.json", summary)
    shown = (f"frames {frames[0]}..{frames[-1]} ({len(frames)})" if sequence
             else f"frame {frames[0]:g}")
    speed = sum(f["rays_per_s"] for f in figures) / len(figures)
    hits = sum(f["hit_pixels"] for f in figures)
    print(f"rendered '{obj.name}' at {shown} through {view}, {args.width}x{args.height}: "
          f"{hits} hit pixels, {speed:,.0f} rays/s -> {args.out}")
    if secondary is not None:
        print(f"  ambient occlusion, shadow and shaded: light "
              f"{figures[0]['secondary']['light']}")
    return 0


def evaluated(args):
    """(report, views, captured) of the evaluate command's ``args``: its JSON report, per
    pose the predicted, true and embedded Passes (``neural.evaluate_model``), and the
    evaluation poses' capture. ``tools/wrong_surface.py`` reads the views as well."""
    from ..blender.steps import evaluate_file
    from ..progress import Progress

    loaded, obj, captured = _model_scene(args, evaluation=True)
    progress = Progress(f"evaluate '{obj.name}'", len(captured.poses), "poses")
    report, views = evaluate_file(obj, captured, args.model, args.width, args.height,
                                  args.device, lambda done, _: progress.update(done),
                                  loaded=loaded, secondary=secondary_settings(args, obj),
                                  precision=args.precision)
    report["pose_set"] = asked_pose_set(args)
    return report, views, captured


def cmd_evaluate(args):
    """Evaluate a trained model on unseen poses against the true and embedded references."""
    from ..blender.steps import DistanceScale, write_figures, write_passes
    from ..inference.metrics import check_compared
    from ..output_rule import all_or_nothing

    report, views, captured = evaluated(args)
    check_compared(report["vs_true"], report["object"])
    with all_or_nothing():          # the figures, passes and report together, or none
        if args.out is not None:
            view = views[0]
            report["figures"] = {name: str(path) for name, path in write_figures(
                args.out, view, args.height, args.width, captured.mesh.size).items()}
            scale, secondary = DistanceScale(), view.get("secondary", {})
            shaded = view.get("shaded", {})
            scale(view["predicted"], view["true"])   # prediction and reference on one scale
            report["passes"] = [str(path) for name in ("predicted", "true") for path in
                                write_passes(args.out, view[name], args.height, args.width,
                                             prefix="" if name == "predicted" else "true-",
                                             secondary=secondary.get(name), scale=scale,
                                             shaded=shaded.get(name))]
        write_json(args.json, report)
    print_evaluation(report)
    print(f"  verdict against the mesh: {verdict(report['vs_true'])}")
    return 0


def _model_command(commands, name, run, notes):
    """A command that uses a trained model on a scene; the resolution is the model's."""
    parser = commands.add_parser(name, help=run.__doc__, description=f"{run.__doc__} {notes}")
    parser.add_argument("--model", type=pathlib.Path, required=True, metavar="MODEL",
                        help="a model file written by 'train' or 'demo'")
    add_scene_options(parser)
    add_setting(parser, declared.RESOLUTION, name,
                help="voxel resolution, which must match the model's (default: the model's)")
    add_pose_options(parser, name)
    add_stress_options(parser)
    add_image_options(parser, name)
    add_setting(parser, declared.DEVICE, name)
    add_setting(parser, declared.PRECISION, name)
    add_secondary_options(parser, name, SHADED_HELP)
    parser.set_defaults(run=run)
    return parser


def add_commands(commands):
    """Adds the model commands to the batch parser's subcommands ``commands``."""
    render = _model_command(commands, "render", cmd_render, (
        "Writes per pass (hit, distance, normal, albedo, material) a PNG transparent where "
        "rays miss, one multilayer EXR of Cycles-named passes (Depth in world units, "
        "Normal, DiffCol, IndexMA, alpha in Combined; AO, Shadow and Shaded with "
        "--secondary) and "
        "render.json into --out."))
    when = render.add_mutually_exclusive_group()
    when.add_argument("--frame", type=float, metavar="F", help="the timeline frame to pose the "
                      "scene at (default: the scene's current frame)")
    when.add_argument("--frames", type=frames_option, metavar="A:B[:STEP]",
                      help="frames A to B every STEP, as image sequences (passes.0001.exr)")
    render.add_argument("--camera", metavar="NAME", help=(
        "camera object (default: the scene's camera, else an orbit viewpoint)"))
    render.add_argument("--references", action="store_true",
                        help="also render the true and embedded references")
    render.add_argument("--out", type=output_folder, required=True, metavar="DIR",
                        help="output folder")

    evaluate = _model_command(commands, "evaluate", cmd_evaluate, (
        "Poses are the evaluation poses of --seed: another random seed or frames between "
        "the training frames, never trained on. Writes --json with variant, config, vs_true "
        "and vs_embedded (distance_mae in object units, normal_error_deg, hit_iou, "
        "albedo_psnr, material_accuracy), timings, thresholds (the model's calibrated ones) "
        "and model_bytes."))
    evaluate.add_argument("--rest-pose", action="store_true",
                          help="evaluate on views of the undeformed rest pose instead")
    add_pose_set_option(evaluate)
    evaluate.add_argument("--out", type=output_folder, metavar="DIR",
                          help="write the figures, error images and first pose's passes here")
    evaluate.add_argument("--json", type=output_file, metavar="PATH", help="write the report "
                          "(vs_true, vs_embedded, per_pose, timings)")
