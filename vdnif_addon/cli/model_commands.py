"""The batch commands on a trained model: render and evaluate. Each reads the --model file
once and captures the scene of the options again as the model was trained on it
(``jobs.model_capture``)."""

import pathlib

from ..inference.metrics import verdict
from ..pose_sets import POSE_SETS, TEST_POSES
from ..settings import COMMAND_IMAGE, EVALUATION_POSES
from .options import (
    add_device_option,
    add_pose_options,
    add_precision_option,
    add_scene_options,
    add_secondary_options,
    add_stress_options,
    check_resolution,
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
    the model was trained on it (``jobs.model_capture``: at --resolution when given, else the
    model's; with ``evaluation`` on evaluation poses, or views of the rest pose)."""
    from ..blender.jobs import model_capture
    from ..model.model_file import load_model

    check_resolution(args.resolution)
    loaded, asked = load_model(args.model), args.resolution
    obj, spec = load_posed_scene(args)
    captured = model_capture(obj, loaded[1], spec, evaluation, resolution=asked,
                             rest=getattr(args, "rest_pose", False),
                             pose_set=getattr(args, "pose_set", TEST_POSES))
    args.resolution = captured.grid.resolution
    return loaded, obj, captured


def cmd_render(args):
    """Render the predicted passes of a pose, or of a range of frames, through a camera with a
    trained model."""
    import bpy

    from ..blender.animation import frame_pose, render_frames
    from ..blender.jobs import write_view
    from ..blender.neural import camera_view, load_scene_model
    from ..blender.pose_reader import PoseReader
    from ..blender.poses import posed
    from ..blender.scenes import find_camera
    from ..kernels import runtime
    from ..output_rule import all_or_nothing
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

    def write(frame, result):
        written.extend(write_view(args.out, result, args.height, args.width, slots,
                                  args.references, frame if sequence else None))

    reader = PoseReader(obj, captured, None if camera is None else (
        lambda: camera_view(camera, args.width, args.height)))
    # Every file of the run (each frame's PNGs and EXR, render.json) is written to a
    # temporary and takes its name only once all are written: a failure leaves the old set.
    with all_or_nothing():
        try:
            figures = render_frames(reader, captured, model, frames, args.width, args.height,
                                    references=args.references, each=write,
                                    progress=(lambda done, _: progress.update(done)) if sequence
                                    else None, secondary=secondary)
        finally:
            reader.close()
        summary = {"model": str(args.model), "object": obj.name, "view": view,
                   "width": args.width, "height": args.height, "kernels_s": kernels_s,
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
        print(f"  ambient occlusion and shadow: light {figures[0]['secondary']['light']}")
    return 0


def evaluated(args):
    """(report, views, captured) of the evaluate command's ``args``: its JSON report, per
    pose the predicted, true and embedded Passes (``neural.evaluate_model``), and the
    evaluation poses' capture. ``tools/wrong_surface.py`` reads the views as well."""
    from ..blender.jobs import evaluate_file
    from ..progress import Progress

    loaded, obj, captured = _model_scene(args, evaluation=True)
    progress = Progress(f"evaluate '{obj.name}'", len(captured.poses), "poses")
    report, views = evaluate_file(obj, captured, args.model, args.width, args.height,
                                  args.device, lambda done, _: progress.update(done),
                                  loaded=loaded, secondary=secondary_settings(args, obj),
                                  precision=args.precision)
    return report, views, captured


def cmd_evaluate(args):
    """Evaluate a trained model on unseen poses against the true and embedded references."""
    from ..blender.jobs import write_figures, write_passes
    from ..output_rule import all_or_nothing

    report, views, captured = evaluated(args)
    with all_or_nothing():          # the figures, passes and report together, or none
        if args.out is not None:
            report["figures"] = {name: str(path) for name, path in write_figures(
                args.out, views[0], args.height, args.width, captured.mesh.size).items()}
            report["passes"] = [str(path) for name in ("predicted", "true") for path in
                                write_passes(args.out, views[0][name], args.height,
                                             args.width,
                                             prefix="" if name == "predicted" else "true-")]
        write_json(args.json, report)
    print_evaluation(report)
    print(f"  verdict against the mesh: {verdict(report['vs_true'])}")
    return 0


def _model_command(commands, name, run, default_poses, notes):
    """A command that uses a trained model on a scene; the resolution is the model's."""
    parser = commands.add_parser(name, help=run.__doc__, description=f"{run.__doc__} {notes}")
    parser.add_argument("--model", type=pathlib.Path, required=True, metavar="MODEL",
                        help="a model file written by 'train' or 'demo'")
    add_scene_options(parser)
    parser.add_argument("--resolution", type=int, metavar="R",
                        help="voxel resolution (default: the model's; must match it)")
    add_pose_options(parser, default_poses)
    add_stress_options(parser)
    parser.add_argument("--width", type=int, default=COMMAND_IMAGE[0], metavar="W")
    parser.add_argument("--height", type=int, default=COMMAND_IMAGE[1], metavar="H")
    add_device_option(parser)
    add_precision_option(parser)
    add_secondary_options(parser)
    parser.set_defaults(run=run)
    return parser


def add_commands(commands):
    """Adds the model commands to the batch parser's subcommands ``commands``."""
    render = _model_command(commands, "render", cmd_render, 1, (
        "Writes per pass (hit, distance, normal, albedo, material) a PNG transparent where "
        "rays miss, one multilayer EXR of Cycles-named passes (Depth in world units, "
        "Normal, DiffCol, IndexMA, alpha in Combined) and render.json into --out."))
    when = render.add_mutually_exclusive_group()
    when.add_argument("--frame", type=float, metavar="F",
                      help="the timeline frame to pose the scene at (default: current)")
    when.add_argument("--frames", type=frames_option, metavar="A:B[:STEP]",
                      help="frames A to B every STEP, as image sequences (passes.0001.exr)")
    render.add_argument("--camera", metavar="NAME", help=(
        "camera object (default: the scene's camera, else an orbit viewpoint)"))
    render.add_argument("--references", action="store_true",
                        help="also render the true and embedded references")
    render.add_argument("--out", type=output_folder, required=True, metavar="DIR")

    evaluate = _model_command(commands, "evaluate", cmd_evaluate, EVALUATION_POSES, (
        "Poses are the evaluation poses of --seed: another random seed or frames between "
        "the training frames, never trained on. Writes --json with variant, config, vs_true "
        "and vs_embedded (distance_mae in object units, normal_error_deg, hit_iou, "
        "albedo_psnr, material_accuracy), timings and model_bytes."))
    evaluate.add_argument("--rest-pose", action="store_true",
                          help="evaluate on views of the undeformed rest pose instead")
    evaluate.add_argument("--pose-set", choices=tuple(POSE_SETS), default=TEST_POSES,
                          help="the unseen poses: the test set, reported; or the "
                               "development set, for choices (default test)")
    evaluate.add_argument("--out", type=output_folder, metavar="DIR",
                          help="write the figures, error images and first pose's passes here")
    evaluate.add_argument("--json", type=output_file, metavar="PATH")
