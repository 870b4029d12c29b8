"""The batch commands behind ``batch.py``: argument parsing and one function per command.

Each command prints its summary to stdout, progress to stderr, and a failure as one line
``vdnif: error: ...`` with a non-zero exit code.
"""

import argparse
import json
import pathlib
import sys

from .errors import VDNIFError


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage mistake on one line, like every other failure."""

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
    """Writes ``data`` as JSON to ``path`` atomically (no half-written file on failure)."""
    if path is None:
        return
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


def check_resolution(value):
    from .voxels import MAX_RESOLUTION, MIN_RESOLUTION

    if not MIN_RESOLUTION <= value <= MAX_RESOLUTION:
        raise VDNIFError(f"resolution {value} is outside {MIN_RESOLUTION}..{MAX_RESOLUTION}")


def cmd_capture(args):
    """Capture a scene: rest mesh, voxels, deformed corners per pose."""
    from .blender.capture import capture
    from .progress import Progress

    check_resolution(args.resolution)
    spec = pose_spec(args)
    obj = load_scene(args)
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
    from .progress import Progress

    check_resolution(args.resolution)
    if args.rays_per_pose < 1:
        raise VDNIFError(f"rays per pose {args.rays_per_pose} must be at least 1")
    spec = pose_spec(args)
    obj = load_scene(args)
    result = capture(obj, args.resolution, spec, deform_corners=False)
    pose_range = parse_range(args.pose_range, len(result.poses))
    progress = Progress(f"dataset '{obj.name}'", pose_range[1] - pose_range[0], "poses")
    header = generate_dataset(obj, result, args.out, args.rays_per_pose,
                              args.surface_fraction, args.seed, pose_range,
                              progress=lambda done, _: progress.update(done))
    counts, timings = header["counts"], header["timings"]
    walk_and_truth = timings["walk_s"] + timings["ground_truth_s"]
    print(f"dataset '{header['object']}' poses {pose_range[0]}:{pose_range[1]} -> {args.out}")
    print(f"  rays {counts['rays']}, segments {counts['segments']}, hits {counts['hits']}")
    walk_numpy = timings["walk_s"] - timings["walk_entry_bvh_s"]
    bvh = timings["walk_entry_bvh_s"] + timings["ground_truth_bvh_s"]
    print(f"  {counts['segments'] / walk_and_truth:,.0f} segments/s, "
          f"{counts['rays'] / walk_and_truth:,.0f} rays/s; vectorized walk {walk_numpy:.2f} s,"
          f" BVHTree casts {bvh:.2f} s (entry {timings['walk_entry_bvh_s']:.2f} s, segments "
          f"{timings['ground_truth_bvh_s']:.2f} s), other ground truth "
          f"{timings['ground_truth_s'] - timings['ground_truth_bvh_s']:.2f} s, pose "
          f"preparation {timings['prepare_s']:.2f} s")
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
    obj = load_scene(args)
    result = capture(obj, args.resolution, evaluation_spec(pose_spec(args)),
                     deform_corners=False)
    progress = Progress(f"references '{obj.name}'", len(result.poses), "poses")
    report = reference_run(obj, result, args.width, args.height, rest_pose=args.rest_pose,
                           progress=lambda done, _: progress.update(done))
    write_json(args.json, report)
    error = report["embedded_vs_true"]
    print(f"references '{report['object']}' R={report['resolution']}, {report['poses']} "
          f"{'rest' if args.rest_pose else 'unseen'} poses, {args.width}x{args.height}")
    print(f"  embedded vs true: distance MAE {error['distance_mae']:.3g} object units, "
          f"normal error {error['normal_error_deg']:.3g} deg, hit IoU {error['hit_iou']:.4f}")
    print(f"  {report['rays_per_s']:,.0f} rays/s, {report['segments_per_s']:,.0f} segments/s")
    return 0


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


def cmd_train(args):
    """Train a network on a dataset folder and write the model file."""
    from .dataset import read_dataset
    from .model_file import model_bytes, save_model
    from .train import train
    from .variants import variant_config

    header, shards = read_dataset(args.data)
    overrides = {field: getattr(args, option[2:].replace("-", "_"))
                 for option, (field, _, _) in NETWORK_OPTIONS.items()
                 if getattr(args, option[2:].replace("-", "_")) is not None}
    overrides.update(steps=args.steps, batch_size=args.batch, device=args.device,
                     seed=args.seed)
    variant = variant_config(args.variant, **overrides)
    network_config = variant.network.__class__.from_dict(
        dict(variant.network.to_dict(), heads=dict(
            albedo=bool(header["heads"]["albedo"]),
            material_count=int(header["heads"]["material_count"]))))
    out = args.out or pathlib.Path(args.data) / f"{args.variant}.vdnif"

    def report(record):
        losses = ", ".join(f"{k} {v:.4f}" for k, v in record["losses"].items())
        print(f"train: step {record['step']}/{record['steps']}, loss {record['total']:.4f} "
              f"({losses}), {record['samples_per_s']:,.0f} samples/s, "
              f"ETA {record['eta_s']:.0f} s", file=sys.stderr, flush=True)

    result = train(shards, header, variant.train, network_config, progress=report)
    if not result.is_main:
        return 0
    extra = {"object": header["object"], "object_size": header["object_size"],
             "grid": header["grid"], "heads": header["heads"],
             "albedo_table": header["albedo_table"], "variant": args.variant,
             "dataset": {"folder": str(args.data), "shards": header["shards"],
                         "poses": len(header["poses"]), "segments": header["segments"]}}
    save_model(out, result.network, result.network_config, result.info(), extra)
    summary = {"variant": args.variant, "model": str(out), "model_bytes": model_bytes(out),
               "train": result.info(), "network_config": result.network_config.to_dict()}
    write_json(args.json, summary)
    print(f"trained {args.variant} on '{header['object']}' ({header['segments']} segments): "
          f"{result.status} after {result.steps} steps in {result.seconds:.1f} s, "
          f"{result.samples_per_s:,.0f} samples/s")
    if result.validation:
        print("  validation on held-out poses: " + ", ".join(
            f"{k} {v:.4g}" for k, v in result.validation.items()))
    print(f"  model {out} ({summary['model_bytes']:,} bytes)")
    return 0


def cmd_bench_network(args):
    """Measure encoder+MLP inference segments/s and training samples/s (paper setting)."""
    from .network_bench import benchmark_network

    result = benchmark_network(device=args.device, repeats=args.repeats)
    write_json(args.json, result)
    print(f"network ({result['device']}, {result['threads']} threads): "
          f"{result['infer_segments_per_s']:,.0f} segments/s inference, "
          f"{result['train_samples_per_s']:,.0f} samples/s training; inference split: "
          f"encoding {result['encode_fraction']:.0%}, MLP {result['mlp_fraction']:.0%}")
    return 0


def add_capture_options(parser, default_poses):
    parser.add_argument("--resolution", type=int, default=32, metavar="R",
                        help="voxels along the longest side, 4..256 (default 32)")
    add_pose_options(parser, default_poses)


def _scene_command(commands, name, run, default_poses, notes):
    """A command that reads a scene: scene, resolution and pose options."""
    parser = commands.add_parser(name, help=run.__doc__, description=f"{run.__doc__} {notes}")
    add_scene_options(parser)
    add_capture_options(parser, default_poses)
    parser.set_defaults(run=run)
    return parser


def build_parser():
    parser = _Parser(prog="batch.py", description=(
        "VDNIF batch commands. Run as: blender --background --python vdnif_addon/batch.py "
        "-- <command> [options], or python vdnif_addon/batch.py -- <command> [options]."))
    commands = parser.add_subparsers(dest="command", metavar="<command>", parser_class=_Parser)
    capture = _scene_command(commands, "capture", cmd_capture, 8, (
        "Writes --json with grid_dims, voxel_size, occupied_voxels, corners, poses, "
        "inverted_cells (per pose), heads and capture_s."))
    capture.add_argument("--json", type=pathlib.Path, metavar="PATH",
                         help="write the summary as JSON")

    data = _scene_command(commands, "dataset", cmd_dataset, 32, (
        "Several processes may each write the shard of their --pose-range into one folder; "
        "training reads them all."))
    data.add_argument("--rays-per-pose", type=int, default=4096, metavar="K",
                      help="training rays per pose (default 4096)")
    data.add_argument("--surface-fraction", type=float, default=0.6, metavar="F",
                      help="share of rays aimed at the surface, the rest at random points "
                           "in the bounds (default 0.6)")
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
    training.add_argument("--data", type=pathlib.Path, required=True, metavar="DIR",
                          help="dataset folder written by 'dataset'")
    training.add_argument("--variant", choices=("lsnif", "deformed", "proposed"),
                          default="proposed")
    training.add_argument("--steps", type=int, default=2000, metavar="N")
    training.add_argument("--batch", type=int, default=2 ** 14, metavar="B",
                          help="segments per step and process (default 16384)")
    training.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    training.add_argument("--seed", type=int, default=0)
    training.add_argument("--out", type=pathlib.Path, metavar="MODEL",
                          help="model file (default DIR/<variant>.vdnif)")
    training.add_argument("--json", type=pathlib.Path, metavar="PATH")
    group = training.add_argument_group("encoding and network (default: the variant's)")
    for option, (_, kind, text) in NETWORK_OPTIONS.items():
        group.add_argument(option, type=kind, help=text)
    training.set_defaults(run=cmd_train)

    bench = commands.add_parser("bench-network", help=cmd_bench_network.__doc__,
                                description=cmd_bench_network.__doc__ + " JSON keys "
                                "infer_segments_per_s, train_samples_per_s.")
    bench.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    bench.add_argument("--repeats", type=int, default=5)
    bench.add_argument("--json", type=pathlib.Path, metavar="PATH")
    bench.set_defaults(run=cmd_bench_network)
    return parser


def main(argv):
    """Runs one batch command; returns the process exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 2
        return args.run(args)
    except _UsageError as exc:
        print(f"vdnif: error: {exc}", file=sys.stderr)
        return 2
    except VDNIFError as exc:
        print(f"vdnif: error: {exc}", file=sys.stderr)
        return 1
