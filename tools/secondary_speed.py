"""Secondary rays per second of a model's network (the deformed walk) and of Warp's refit
BVH on one device, for one unseen pose, with no Blender where they are timed: ``capture``
(needs bpy) writes the pose (the rest mesh, the grid's resolution, the deformed corners and
vertices, an orbit view's rays); ``time`` reads it on any machine with torch and Warp, the
GPU machines included, and times each path's primary pass and its secondary rays
(``inference.secondary.secondary_passes`` from its own hits, at each ``--samples``), the
first of ``--repeats`` + 1 rounds a warm-up, medians printed.

    python tools/secondary_speed.py capture out/bunny-pose.npz -- --model out/bunny.vdnif \\
        --scene bunny --width 256 --height 256
    python tools/secondary_speed.py time out/bunny-pose.npz --model out/bunny.vdnif \\
        --device cuda --repeats 5 [--precision float32]

Warp's path refits a BVH of the pose's vertices, casts the primary rays and takes the hit
triangle's geometric normal, as ``side-by-side``'s does; its clock, like the network's,
stops after the device's queued work.
"""

import argparse
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))    # tool_exit, also when run by runpy

import numpy as np  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.settings import DEFAULT_PRECISION, PRECISIONS  # noqa: E402

POSE_KEYS = ("rest_vertices", "triangles", "resolution", "corners", "vertices", "origins",
             "directions", "object_size")


def capture(out, evaluate_options):
    """Writes the first evaluation pose of ``evaluate``'s options to ``out`` (.npz)."""
    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.model_commands import _model_scene
    from vdnif_addon.cli.options import validate_arguments
    from vdnif_addon.posed.geometry import PosedObject
    from vdnif_addon.posed.render import orbit_view
    from vdnif_addon.tracing.rays import orbit_viewpoints

    args = build_parser().parse_args(["evaluate", *evaluate_options])
    validate_arguments(args)
    _, obj, captured = _model_scene(args, evaluation=True)
    with PosedObject(obj, captured, "cpu") as posed_object:
        geometry = posed_object.geometry(captured.poses[0])
        origins, directions = orbit_view(geometry, orbit_viewpoints(1)[0], args.width,
                                         args.height)
        np.savez_compressed(out, rest_vertices=captured.mesh.vertices,
                            triangles=captured.mesh.triangles,
                            resolution=captured.grid.resolution, corners=geometry.corners,
                            vertices=geometry.vertices, origins=origins,
                            directions=directions, object_size=captured.mesh.size)
    print(f"wrote {out}: '{obj.name}', {len(origins):,} rays")


def read_pose(path):
    """The pose file's arrays; a file that is not one raises a one-line VDNIFError."""
    try:
        with np.load(path) as data:
            missing = [key for key in POSE_KEYS if key not in data.files]
            if missing:
                raise VDNIFError(f"{path} is not a pose file of this tool (no "
                                 f"{', '.join(missing)})")
            return {key: data[key] for key in POSE_KEYS}
    except (OSError, ValueError) as error:
        raise VDNIFError(f"{path} is not a readable pose file ({error})") from None


def time_paths(path, model_path, device_name, repeats, samples, precision=DEFAULT_PRECISION):
    """Prints each path's medians at each AO sample count, the network's MLPs in
    ``precision`` as a render resolves it on the device."""
    import torch

    from vdnif_addon.geometry import voxels
    from vdnif_addon.inference.neural_render import neural_passes
    from vdnif_addon.inference.secondary import (
        SecondarySettings,
        counted,
        exact_occluded,
        mesh_primary,
        model_offset,
        neural_occluded,
        secondary_passes,
    )
    from vdnif_addon.kernels import runtime
    from vdnif_addon.kernels.cast import MeshCaster
    from vdnif_addon.kernels.cells import DeviceCells
    from vdnif_addon.model.model_file import load_model
    from vdnif_addon.model.network import resolve_precision
    from vdnif_addon.training.distributed import resolve_device

    pose = read_pose(path)
    device = resolve_device(device_name)
    network, metadata = load_model(model_path)
    grid = voxels.build_grid(pose["rest_vertices"], pose["triangles"], int(pose["resolution"]))
    if not np.isclose(grid.voxel_size, metadata.grid.voxel_size, rtol=1e-6):
        raise VDNIFError(f"model {model_path} was not trained on the mesh of {path}")
    network = network.to(device)
    network.precision = resolve_precision(precision, device)
    table = metadata.albedo_colors()
    origins, directions = pose["origins"], pose["directions"]
    size = float(pose["object_size"])
    kernels_s = runtime.load_all(runtime.device(device))
    where = str(device) if device.type == "cpu" else (
        f"{device} ({torch.cuda.get_device_name(device)})")
    print(f"{where}: kernels ready in {kernels_s:.1f} s, apart; torch on "
          f"{torch.get_num_threads()} thread(s); the MLPs in {network.precision}; "
          f"{len(origins):,} primary rays")

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    cells = DeviceCells(grid, str(device), corners=pose["corners"])
    caster = MeshCaster(pose["vertices"], pose["triangles"], str(device))
    offset = model_offset(metadata, size, grid.voxel_size)

    def neural():
        primary, _ = neural_passes(network, grid, table, cells, origins, directions, device)
        return primary, neural_occluded(network, grid, table, cells, offset, device), offset

    def warp():
        caster.refit(pose["vertices"])
        index, t = caster.cast(origins, directions, np.inf)
        return mesh_primary(pose["vertices"], pose["triangles"], index, t), \
            exact_occluded(caster), None

    for count in samples:
        settings = SecondarySettings(samples=count)
        for name, prepare in (("network", neural), ("Warp refit", warp)):
            primary_s, secondary_s = [], []
            for round_ in range(repeats + 1):
                cast = []
                sync()
                start = time.perf_counter()
                primary, occluded, at = prepare()
                sync()
                middle = time.perf_counter()
                passes = secondary_passes(primary, origins, directions,
                                          counted(occluded, cast), size, settings, at)
                sync()
                if round_:
                    primary_s.append(middle - start)
                    secondary_s.append(time.perf_counter() - middle)
            first, second = statistics.median(primary_s), statistics.median(secondary_s)
            hits = passes.hit
            print(f"{name}, {count} AO sample(s): primary {1e3 * first:.1f} ms "
                  f"({len(origins) / first / 1e6:.2f} M rays/s); secondary {sum(cast):,} rays "
                  f"{1e3 * second:.1f} ms ({sum(cast) / second / 1e6:.2f} M rays/s); "
                  f"{int(hits.sum()):,} hits, mean AO {passes.ao[hits].mean():.3f}, "
                  f"lit {passes.lit[hits].mean():.3f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    take = commands.add_parser("capture", help="write one evaluation pose (needs bpy)")
    take.add_argument("out", type=pathlib.Path, help="the pose file to write (.npz)")
    take.add_argument("evaluate", nargs=argparse.REMAINDER,
                      help="after --: evaluate's options (--model, --scene, --width, ...)")
    timed = commands.add_parser("time", help="time both paths on a pose file")
    timed.add_argument("pose", type=pathlib.Path, help="a pose file written by capture")
    timed.add_argument("--model", type=pathlib.Path, required=True,
                       help="the model file the pose was captured for")
    timed.add_argument("--device", default="auto", help="auto, cpu or cuda")
    timed.add_argument("--repeats", type=int, default=5, help="timed rounds after a warm-up")
    timed.add_argument("--samples", type=int, nargs="+", default=[1, 16],
                       help="AO samples per pixel to time")
    timed.add_argument("--precision", default=DEFAULT_PRECISION, choices=PRECISIONS,
                       help="the MLPs' arithmetic, as a render resolves it on the device "
                       f"(default: {DEFAULT_PRECISION})")
    args = parser.parse_args()
    if args.command == "capture":
        capture(args.out, [a for a in args.evaluate if a != "--"])
    else:
        if args.repeats < 1:
            raise VDNIFError(f"--repeats must be at least 1, got {args.repeats}")
        time_paths(args.pose, args.model, args.device, args.repeats, args.samples,
                   args.precision)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=VDNIFError, prefix="error: ")
