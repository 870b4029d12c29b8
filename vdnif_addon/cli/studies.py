"""The studies' batch commands: demo, experiment, bench, side-by-side, bench-network; each
maps its options onto a study of ``vdnif_addon/studies`` and prints its summary
(``add_commands`` adds their parsers)."""

import pathlib

from .. import declarations as declared
from ..errors import VDNIFError
from ..inference.metrics import SPEED_MIN_HIT_IOU
from ..safe_io import MARKDOWN_MARK, write_text_atomic
from ..settings import DEFAULT_PRECISION, DEMO_SCENE, DEMO_SCENES, RECIPE
from ..studies.side_by_side_scenes import MILLION_LEVEL, SCENES, scene_name
from .options import (
    add_image_options,
    add_secondary_options,
    add_setting,
    add_stress_options,
    print_evaluation,
    report_training,
    secondary_settings,
    write_json,
)
from .outputs import check_places, output_file, output_folder, output_markdown

# torch, Warp, the baselines and the timing code are imported where they are used, so that
# building the batch parser (every command's, a failing one's too) does not import them.


def cmd_demo(args):
    """The main job on an embedded scene: capture, dataset, train (proposed), render and
    evaluate on unseen poses, and a short report with the figure."""
    from ..blender.extremes import apply_stress
    from ..studies.demo import run_demo

    report = run_demo(args.scene, args.out, quick=args.quick, device=args.device,
                      steps=args.steps, progress=report_training,
                      stress=lambda obj, spec: apply_stress(args, obj, spec))
    write_json(args.json, report)
    print_evaluation(report)
    print(f"  report {report['report']}")
    return 0


def cmd_experiment(args):
    """Run one of the paper's experiments and write its section of the results file."""
    from ..studies.experiments import run_experiment
    from ..text import value

    scenes = args.scenes.split(",") if args.scenes else None
    records = run_experiment(args.name, args.results, quick=args.quick, device=args.device,
                             progress=report_training, scenes=scenes, seeds=args.seeds)
    for label, report in records.items():
        m = report.get("common", report)     # the table's figures: the common pixel set
        print(f"{label}: vs true distance MAE {value(m['vs_true']['distance_mae'])} "
              f"({value(m['vs_true'].get('distance_mae_voxels'))} voxels), normal error "
              f"{value(m['vs_true']['normal_error_deg'])} deg, hit IoU "
              f"{value(m['vs_true']['hit_iou'])}; vs embedded "
              f"{value(m['vs_embedded']['distance_mae'])}, "
              f"{value(m['vs_embedded']['normal_error_deg'])} deg")
    print(f"  written to {args.results}")
    return 0


def cmd_bench(args):
    """Sweep resolution, hash grid, PE bands and width, each point trained until the
    stopping rule or the step cap ends it; derive the presets."""
    from ..presets import PRESETS_FILE
    from ..studies.bench import run_bench

    quick_dir = pathlib.Path("out/bench-quick")
    out = args.out or (quick_dir if args.quick else pathlib.Path("docs/bench"))
    presets = args.presets or (quick_dir / "presets.json" if args.quick else PRESETS_FILE)
    performance = args.performance or (None if args.quick else pathlib.Path(
        "docs/performance.md"))
    work = args.work or pathlib.Path("out/bench-quick-work" if args.quick else "out/bench-work")
    check_places([(out, "--out", "folder"), (work, "--work", "folder"),     # the defaults too
                  (presets, "--presets", "json"), (performance, "--performance", "markdown")])
    rows, derived = run_bench(out, presets, work, performance, quick=args.quick,
                              device=args.device, progress=report_training)
    if rows is None:        # another run on the same work folder evaluates every point
        print(f"bench: trained this run's share of the points in {work}; no outputs written "
              "by this run")
        return 0
    print(f"bench: {len(rows)} points -> {out}/bench.csv, bench.json, pareto.png; presets "
          + (f"n/a ({derived}; {presets} left as it was)" if isinstance(derived, str) else
             f"-> {presets}" + "".join(f" ({name} dropped: {reason})"
                                       for name, reason in derived[1].items()))
          + (f"; section of {performance}" if performance else ""))
    return 0


def cmd_bench_network(args):
    """Measure encoder+MLP inference segments/s and training samples/s (paper setting)."""
    from ..studies.network_bench import benchmark_network

    result = benchmark_network(device=args.device, repeats=args.repeats,
                               precision=args.precision)
    write_json(args.json, result)
    print(f"network ({result['device']}, {result['threads']} torch threads, MLPs in "
          f"{result['precision']}): "
          f"{result['infer_segments_per_s']:,.0f} segments/s inference "
          f"({result['serial_segments_per_s']:,.0f} with the encoder and the MLP one after "
          f"the other: encoder {result['encode_fraction']:.0%}, MLP {result['mlp_fraction']:.0%}"
          f"), {result['train_samples_per_s']:,.0f} samples/s training")
    return 0


def cmd_side_by_side(args):
    """Time the neural path against Blender's BVHTree, Warp's refit BVH and Embree (refit
    and rebuilt) per pose at 1 thread and at every core, the deformed walk against a static
    DDA walk, and model bytes against mesh + BVH bytes."""
    import os
    import shlex

    from ..progress import Progress
    from ..studies.side_by_side import compare_paths, machine, thread_settings
    from ..studies.side_by_side_report import (
        machine_text,
        side_by_side_markdown,
        write_performance,
        write_plots,
    )
    from ..studies.side_by_side_scenes import load_side_by_side_scene, save_blends
    from ..training.distributed import resolve_device

    scenes = list(dict.fromkeys(scene_name(name) for name in args.scene))
    if args.save_blend is not None:
        return save_blends(scenes, args.save_blend)
    settings = thread_settings(args.thread_settings)
    sizes = _image_sizes(args)
    if args.crossover is not None and sum(s.startswith("suzanne-") for s in scenes) < 2:
        raise VDNIFError("--crossover needs at least two suzanne-N scenes in --scene: the "
                         "crossing is found on the Suzanne sweep")
    models = _model_paths(args.model, scenes)
    device = resolve_device(args.device)
    if args.train is not None:
        from ..studies.side_by_side import recipe_model

        for name in (name for name in scenes if name not in models):
            models[name] = recipe_model(name, args.train, args.seed, args.device, args.quick,
                                        report_training)
    load_before = os.getloadavg()[0]
    results = []
    for name in scenes:
        obj = load_side_by_side_scene(name)
        captured, model = _scene_capture(obj, models.get(name), args, device)
        secondary = secondary_settings(args, obj)
        for (width, height), threads in ((size, t) for size in sizes for t in settings):
            progress = Progress(f"side by side '{obj.name}', {width}x{height}, {threads} "
                                "thread setting", args.repeats, "repeats")
            result = compare_paths(obj, captured, model, width, height, args.repeats,
                                   progress=lambda done, _: progress.update(done),
                                   device=device, threads=threads, secondary=secondary)
            result["scene"] = name
            results.append(result)
            _print_result(result)
    threads = os.environ.get("OMP_NUM_THREADS")
    command = ((f"OMP_NUM_THREADS={threads} " if threads else "")
               + shlex.join(["python", "vdnif_addon/batch.py", "--", *command_line(args)]))
    host = machine(load_before, device)
    write_json(args.json, {"command": command, "machine": host, "results": results})
    if args.markdown is not None:
        write_text_atomic(args.markdown, "\n".join([MARKDOWN_MARK, *side_by_side_markdown(
            results, command, machine_text(host))]) + "\n", "markdown file", "markdown")
    if args.plots is not None:
        write_plots(results, args.plots)
    if args.performance is not None:
        write_performance(args.performance, results, command, host)
    if args.crossover is not None:
        _write_crossover(args.crossover, results, command, host)
    return 0


def _image_sizes(args):
    """(width, height) of every image size to time: --width x --height, then the preview."""
    preview = args.preview
    if preview is None and args.crossover is not None:
        from ..studies.side_by_side_crossover import PREVIEW

        preview = PREVIEW
    sizes = [(args.width, args.height)]
    return sizes + ([] if preview is None or (preview, preview) in sizes
                    else [(preview, preview)])


def _write_crossover(folder, results, command, host):
    """crossover.json, crossover.md and crossover.png into ``folder``."""
    from ..studies.side_by_side_crossover import crossover, crossover_markdown
    from ..studies.side_by_side_report import machine_text, write_crossover_plot

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data = crossover(results)
    write_json(folder / "crossover.json", {"command": command, "machine": host, **data})
    write_crossover_plot(data, results, folder / "crossover.png")
    write_text_atomic(folder / "crossover.md", "\n".join(crossover_markdown(
        data, results, command, machine_text(host), "crossover.png")) + "\n", "markdown file")
    for row in data["rows"]:
        print(f"crossover {row['width']}x{row['height']}, {row['threads']} thread setting, "
              f"{row['baseline']}: {row['text']}")


def command_line(args):
    """The arguments of ``side-by-side`` that reproduce a run of ``args``, every setting
    spelled out."""
    line = ["side-by-side", "--scene", *args.scene]
    line += ["--model", *args.model] if args.model else []
    line += ["--resolution", str(args.resolution)] if args.resolution else []
    line += ["--poses", str(args.poses), "--seed", str(args.seed), "--repeats",
             str(args.repeats), "--width", str(args.width), "--height", str(args.height),
             "--threads", *args.thread_settings, "--device", args.device]
    line += ["--precision", args.precision] if args.precision != DEFAULT_PRECISION else []
    line += ["--quick"] if args.quick else []
    line += (["--secondary", "--ao-samples", str(args.ao_samples), "--ao-distance",
              str(args.ao_distance)] if args.secondary else [])
    for option in ("preview", "train", "json", "markdown", "plots", "performance",
                   "crossover"):
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
    model's training poses; the resolution is --resolution, else the model's, else the
    recipe's of the mesh."""
    from ..blender.resolution import recipe_resolution
    from ..blender.steps import model_capture
    from ..model.model_file import load_model
    from ..pose_sets import PoseSpec
    from ..posed.render import load_scene_model

    loaded = None if model_path is None else load_model(model_path)
    metadata = None if loaded is None else loaded[1]
    resolution = args.resolution or (None if metadata else recipe_resolution(obj))
    captured = model_capture(obj, metadata, PoseSpec(count=args.poses, seed=args.seed),
                             evaluation=True, resolution=resolution)
    model = (None if loaded is None
             else load_scene_model(model_path, captured, device, loaded, args.precision))
    return captured, model


def _print_result(result):
    from ..studies.baselines import BASELINES

    ratios, speeds = result["ratios"], result["rays_per_s"]

    def ratio(name):
        return "n/a" if ratios[name] is None else f"{ratios[name]:.3g}x"

    neural = ("n/a" if speeds["neural"] is None else f"{speeds['neural']:,.0f} rays/s")
    print(f"side by side '{result['object']}' ({result['triangles']:,} triangles), "
          f"{result['width']}x{result['height']}, {result['threads']['setting']} thread "
          f"setting, medians of {result['repeats']} repeats: neural render {neural}"
          + (f" ({result['speed_withheld']})" if result["speed_withheld"] else "")
          + "; pose total " + ", ".join(f"{ratio(f'pose_neural_over_{b}')} {b}"
                                        for b in BASELINES)
          + "; preparation " + ", ".join(f"{ratio(f'prepare_neural_over_{b}')} {b}"
                                         for b in BASELINES)
          + f"; deformed walk {ratio('walk_deformed_over_static')} the static DDA walk, "
          f"{ratio('walk_and_network_deformed_over_static')} with the network")
    if "secondary" in result:
        from ..studies.side_by_side_report import secondary_line

        print(secondary_line(result))


def add_commands(commands):
    """Adds the studies' commands to the batch parser's subcommands ``commands``."""
    demo = commands.add_parser("demo", help=cmd_demo.__doc__, description=cmd_demo.__doc__)
    demo.add_argument("--scene", choices=DEMO_SCENES, default=DEMO_SCENE,
                      help=f"an embedded demo scene (default {DEMO_SCENE})")
    demo.add_argument("--quick", action="store_true", help="a small size, for tests")
    add_stress_options(demo)
    add_setting(demo, declared.STEPS, "demo", help="training steps (default: the demo's own)")
    add_setting(demo, declared.DEVICE, "demo")
    demo.add_argument("--out", type=output_folder, default="out/demo",
                      metavar="DIR", help="output folder")
    demo.add_argument("--json", type=output_file, metavar="PATH",
                      help="also write the report JSON here (it is always in DIR)")
    demo.set_defaults(run=cmd_demo)

    experiment = commands.add_parser("experiment", help=cmd_experiment.__doc__,
                                     description=cmd_experiment.__doc__)
    experiment.add_argument("name", choices=("static", "deformation", "ablation", "per-pose"),
                            help="the experiment")
    experiment.add_argument("--quick", action="store_true", help="a tiny size, for tests")
    experiment.add_argument("--scenes", metavar="A,B", help="only these of the experiment's "
                            "scenes, which its section names (default: all)")
    experiment.add_argument("--seeds", type=int, metavar="N", help="only the first N of the "
                            "size's seeds (default: all)")
    add_setting(experiment, declared.DEVICE, "experiment")
    experiment.add_argument("--results", type=output_markdown,
                            default="docs/results.md", metavar="PATH",
                            help="markdown file whose section is rewritten; figures and "
                                 "JSON go to results/ beside it")
    experiment.set_defaults(run=cmd_experiment)

    sweep = commands.add_parser("bench", help=cmd_bench.__doc__, description=(
        cmd_bench.__doc__ + " Each point trains the proposed variant on the arm and evaluates "
        "it on unseen poses (accuracy against both references, training time, render rays/s, "
        "model bytes). A run again on the same --work folder trains only the unfinished "
        "points, and runs side by side on one folder share them."))
    sweep.add_argument("--quick", action="store_true",
                       help="a small sweep (minutes) into out/bench-quick, presets not shipped")
    sweep.add_argument("--out", type=output_folder, metavar="DIR",
                       help="bench.csv, bench.json, pareto.png (default docs/bench)")
    sweep.add_argument("--presets", type=output_file, metavar="PATH",
                       help="presets JSON (default: the one the panel reads)")
    sweep.add_argument("--performance", type=output_markdown, metavar="PATH",
                       help="markdown whose sweep section is rewritten "
                            "(default docs/performance.md; none with --quick)")
    sweep.add_argument("--work", type=output_folder, metavar="DIR",
                       help="each point's model and training record (default "
                            "out/bench-work, out/bench-quick-work with --quick)")
    add_setting(sweep, declared.DEVICE, "bench")
    sweep.set_defaults(run=cmd_bench)

    _add_side_by_side(commands)

    bench = commands.add_parser("bench-network", help=cmd_bench_network.__doc__,
                                description=cmd_bench_network.__doc__ + " JSON keys "
                                "infer_segments_per_s, serial_segments_per_s, "
                                "encode_segments_per_s, mlp_segments_per_s, encode_fraction, "
                                "mlp_fraction, train_samples_per_s, threads, precision "
                                "(the MLPs', in inference and training).")
    add_setting(bench, declared.DEVICE, "bench-network")
    add_setting(bench, declared.PRECISION, "bench-network")
    bench.add_argument("--threads", type=int, metavar="N",
                       help="torch threads (default: the product's, vdnif_addon/threads.py)")
    bench.add_argument("--repeats", type=int, default=5, metavar="N",
                       help="runs; medians are reported")
    bench.add_argument("--json", type=output_file, metavar="PATH",
                       help="write the figures as JSON")
    bench.set_defaults(run=cmd_bench_network)


def _add_side_by_side(commands):
    parser = commands.add_parser("side-by-side", help=cmd_side_by_side.__doc__,
                                 description=cmd_side_by_side.__doc__ + (
                                     " Poses are unseen evaluation poses. suzanne-N is "
                                     "Suzanne subdivided N times with a lattice rig; "
                                     f"'million' is suzanne-{MILLION_LEVEL}. Neural speeds "
                                     "need a model that predicts hits (hit IoU at least "
                                     f"{SPEED_MIN_HIT_IOU} against the true reference); "
                                     "without one they are n/a."))
    parser.add_argument("--scene", nargs="+", choices=SCENES, default=["bunny"],
                        help="one or more scenes")
    parser.add_argument("--model", nargs="+", metavar="[SCENE=]MODEL",
                        help="a model file trained on the scene, or SCENE=MODEL per scene")
    parser.add_argument("--repeats", type=int, default=3, metavar="N",
                        help="timed repeats; medians are reported")
    add_setting(parser, declared.RESOLUTION, "side-by-side", help=(
        f"voxel resolution (default: the model's, else {RECIPE.resolution}, "
        f"{RECIPE.textured_resolution} for a textured mesh)"))
    add_setting(parser, declared.POSES, "side-by-side", help="unseen poses per repeat")
    add_setting(parser, declared.SEED, "side-by-side",
                help="training pose seed; the evaluation poses of it are used")
    add_image_options(parser, "side-by-side")
    parser.add_argument("--preview", type=int, metavar="N",
                        help="also time an NxN preview (default 64 with --crossover)")
    parser.add_argument("--threads", nargs="+", dest="thread_settings", default=["1", "all"],
                        metavar="N|all", help="thread settings to time (default: 1 all)")
    add_setting(parser, declared.DEVICE, "side-by-side")
    add_setting(parser, declared.PRECISION, "side-by-side")
    parser.add_argument("--train", type=output_folder, metavar="DIR", help=(
        "train each scene without --model by the recipe into DIR (kept for the next run)"))
    parser.add_argument("--quick", action="store_true",
                        help="with --train: a tiny training, for tests")
    parser.add_argument("--json", type=output_file, metavar="PATH",
                        help="write every repeat's timings, the medians and ratios as JSON")
    parser.add_argument("--markdown", type=output_markdown, metavar="PATH",
                        help="write the tables as markdown")
    parser.add_argument("--plots", type=output_folder, metavar="DIR",
                        help="write the rays/s and bytes plots into DIR")
    parser.add_argument("--performance", type=output_markdown, metavar="PATH", help=(
        "rewrite the side-by-side section of PATH (docs/performance.md), plots in "
        "side-by-side/ beside it"))
    parser.add_argument("--crossover", type=output_folder, metavar="DIR", help=(
        "write crossover.json, .md and .png into DIR: where neural meets each baseline"))
    parser.add_argument("--save-blend", type=output_folder, metavar="DIR", help=(
        "only save each scene as DIR/<scene>.blend (for 'train --blend') and stop"))
    add_secondary_options(parser, "side-by-side", secondary_help=(
        "also time each path's ambient-occlusion and shadow rays, at 1 and --ao-samples per "
        "pixel"))
    parser.set_defaults(run=cmd_side_by_side)
