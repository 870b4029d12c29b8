"""The ``side-by-side`` batch command: builds each scene, captures unseen poses (disjoint
from the model's training poses), runs ``side_by_side.compare_paths`` and writes the JSON,
tables, plots and the section of ``docs/performance.md`` (``side_by_side_report``); with
``--save-blend`` it only saves the scenes for ``train --blend``."""

import pathlib

import bpy

from ..errors import VDNIFError
from ..safe_io import atomic_path, write_text_atomic
from .side_by_side_scenes import MILLION_LEVEL, SCENES, scene_name

# torch, Warp, the baselines and the timing code are imported where they are used, so that
# building the batch parser (every command's, a failing one's too) does not import them.


def machine(load_before, device):
    """The machine and thread settings of a run on torch ``device``, for the report
    (``load_before``: the load average when it started)."""
    import importlib.metadata
    import os
    import platform

    import torch

    from ..kernels import runtime

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as info:
            cpu = next((line.split(":", 1)[1].strip() for line in info
                        if line.startswith("model name")), cpu)
    except OSError:
        pass
    cores = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
             else os.cpu_count())
    warp = runtime.init()
    return {"cpu": cpu, "cores": cores, "load_before": load_before,
            "load_after": os.getloadavg()[0],
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "torch": torch.__version__, "torch_threads": torch.get_num_threads(),
            "warp": warp.__version__, "warp_device": runtime.device(device),
            "embreex": importlib.metadata.version("embreex"),
            "blender": bpy.app.version_string}


def cmd_side_by_side(args):
    """Time the neural path against Blender's BVHTree, Warp's refit BVH and Embree per
    pose, the deformed walk against a static DDA walk, and model bytes against mesh + BVH
    bytes."""
    import os
    import shlex

    from ..commands import write_json
    from ..progress import Progress
    from ..train import resolve_device
    from .side_by_side import compare_paths, load_side_by_side_scene
    from .side_by_side_report import (
        machine_text,
        side_by_side_markdown,
        write_performance,
        write_plots,
    )

    scenes = list(dict.fromkeys(scene_name(name) for name in args.scene))
    if args.save_blend is not None:
        return _save_blends(scenes, args.save_blend)
    models = _model_paths(args.model, scenes)
    device = resolve_device(args.device)
    load_before = os.getloadavg()[0]
    results = []
    for name in scenes:
        obj = load_side_by_side_scene(name)
        captured, model = _scene_capture(obj, models.get(name), args, device)
        progress = Progress(f"side by side '{obj.name}'", args.repeats, "repeats")
        result = compare_paths(obj, captured, model, args.width, args.height, args.repeats,
                               progress=lambda done, _: progress.update(done),
                               device=device)
        result["scene"] = name
        results.append(result)
        _print_result(result)
    threads = os.environ.get("OMP_NUM_THREADS")
    command = ((f"OMP_NUM_THREADS={threads} " if threads else "")
               + shlex.join(["python", "vdnif_addon/batch.py", "--", *command_line(args)]))
    host = machine(load_before, device)
    write_json(args.json, {"command": command, "machine": host, "results": results})
    if args.markdown is not None:
        write_text_atomic(args.markdown, "\n".join(side_by_side_markdown(
            results, command, machine_text(host))) + "\n", "markdown file")
    if args.plots is not None:
        write_plots(results, args.plots)
    if args.performance is not None:
        write_performance(args.performance, results, command, host)
    return 0


def command_line(args):
    """The arguments of ``side-by-side`` that reproduce a run of ``args``, every setting
    spelled out."""
    line = ["side-by-side", "--scene", *args.scene]
    line += ["--model", *args.model] if args.model else []
    line += ["--resolution", str(args.resolution)] if args.resolution else []
    line += ["--poses", str(args.poses), "--seed", str(args.seed), "--repeats",
             str(args.repeats), "--width", str(args.width), "--height", str(args.height),
             "--device", args.device]
    for option in ("json", "markdown", "plots", "performance"):
        value = getattr(args, option)
        line += [f"--{option}", str(value)] if value is not None else []
    return line


def _model_paths(values, scenes):
    """{scene: model path} from ``--model PATH`` (one scene) or ``SCENE=PATH`` pairs."""
    models = {}
    for value in values or []:
        scene, separator, path = value.rpartition("=")
        if not separator:
            if len(scenes) > 1:
                raise VDNIFError(f"--model {value}: with several scenes name the scene of "
                                 "each model as SCENE=PATH")
            scene = scenes[0]
        scene = scene_name(scene)
        if scene not in scenes:
            raise VDNIFError(f"--model {value}: scene '{scene}' is not among --scene")
        models[scene] = pathlib.Path(path)
    return models


def _scene_capture(obj, model_path, args, device):
    """(capture of unseen poses, SceneModel or None) of one scene: the poses avoid the
    model's training poses; the resolution is --resolution, else the model's, else 32."""
    from ..commands import check_resolution
    from ..model_file import load_model
    from ..blender.capture import capture
    from ..blender.neural import load_scene_model
    from ..blender.poses import PoseSpec, evaluation_spec

    trained, resolution = None, args.resolution
    if model_path is not None:
        extra = load_model(model_path)[1]["extra"]
        trained = extra.get("train_poses") or None
        resolution = resolution or int(extra["grid"]["resolution"])
    resolution = resolution or DEFAULT_RESOLUTION
    check_resolution(resolution)
    spec = evaluation_spec(PoseSpec(count=args.poses, seed=args.seed), trained=trained)
    captured = capture(obj, resolution, spec, deform_corners=False)
    model = (None if model_path is None
             else load_scene_model(model_path, captured, device))
    return captured, model


DEFAULT_RESOLUTION = 32


def _print_result(result):
    from .baselines import BASELINES

    ratios, speeds = result["ratios"], result["rays_per_s"]

    def ratio(name):
        return "n/a" if ratios[name] is None else f"{ratios[name]:.3g}x"

    neural = ("n/a" if speeds["neural"] is None else f"{speeds['neural']:,.0f} rays/s")
    print(f"side by side '{result['object']}' ({result['triangles']:,} triangles), medians "
          f"of {result['repeats']} repeats: neural render {neural}"
          + (f" ({result['speed_withheld']})" if result["speed_withheld"] else "")
          + "; pose total " + ", ".join(f"{ratio(f'pose_neural_over_{b}')} {b}"
                                        for b in BASELINES)
          + "; preparation " + ", ".join(f"{ratio(f'prepare_neural_over_{b}')} {b}"
                                         for b in BASELINES)
          + f"; deformed walk {ratio('walk_deformed_over_static')} the static DDA walk, "
          f"{ratio('walk_and_network_deformed_over_static')} with the network")


def _save_blends(scenes, folder):
    """Saves each scene as ``folder/<scene>.blend`` for ``train --blend`` and says how."""
    from .side_by_side import load_side_by_side_scene

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name in scenes:
        obj = load_side_by_side_scene(name)
        path = folder / f"{name}.blend"
        with atomic_path(path, ".blend file") as temporary:    # copy: the session keeps its file
            bpy.ops.wm.save_as_mainfile(filepath=str(pathlib.Path(temporary).resolve()),
                                        check_existing=False, copy=True)
            pathlib.Path(temporary + "1").unlink(missing_ok=True)  # Blender's backup of it
        print(f"saved scene '{name}' ('{obj.name}') to {path}: train with "
              f"train --blend {path} --object '{obj.name}'")
    return 0


def add_side_by_side_parser(commands):
    """Adds the ``side-by-side`` command to the batch parser's subcommands."""
    from ..commands import add_device_option

    parser = commands.add_parser("side-by-side", help=cmd_side_by_side.__doc__,
                                 description=cmd_side_by_side.__doc__ + (
                                     " Poses are unseen evaluation poses. suzanne-N is "
                                     "Suzanne subdivided N times with a lattice rig; "
                                     f"'million' is suzanne-{MILLION_LEVEL} (1,007,616 "
                                     "triangles)."))
    parser.add_argument("--scene", nargs="+", choices=SCENES, default=["bunny"],
                        help="one or more scenes (default bunny)")
    parser.add_argument("--model", nargs="+", metavar="[SCENE=]MODEL", help=(
        "a model file trained on the scene, or SCENE=MODEL per scene: neural speeds need a "
        "model that predicts hits (hit IoU >= 0.9 against the true reference); without one "
        "they are n/a"))
    parser.add_argument("--repeats", type=int, default=3, metavar="N",
                        help="timed repeats; medians are reported (default 3)")
    parser.add_argument("--resolution", type=int, metavar="R", help=(
        f"voxel resolution (default: the model's, else {DEFAULT_RESOLUTION})"))
    parser.add_argument("--poses", type=int, default=4, metavar="N",
                        help="unseen poses per repeat (default 4)")
    parser.add_argument("--seed", type=int, default=0,
                        help="training pose seed; the evaluation poses of it are used")
    parser.add_argument("--width", type=int, default=256, metavar="W")
    parser.add_argument("--height", type=int, default=256, metavar="H")
    add_device_option(parser, default="cpu")
    parser.add_argument("--json", type=pathlib.Path, metavar="PATH",
                        help="write every repeat's timings, the medians and ratios as JSON")
    parser.add_argument("--markdown", type=pathlib.Path, metavar="PATH",
                        help="write the tables as markdown")
    parser.add_argument("--plots", type=pathlib.Path, metavar="DIR",
                        help="write the rays/s and bytes plots into DIR")
    parser.add_argument("--performance", type=pathlib.Path, metavar="PATH", help=(
        "rewrite the side-by-side section of PATH (docs/performance.md), plots in "
        "side-by-side/ beside it"))
    parser.add_argument("--save-blend", type=pathlib.Path, metavar="DIR", help=(
        "only save each scene as DIR/<scene>.blend (for 'train --blend') and stop"))
    parser.set_defaults(run=cmd_side_by_side)
    return parser
