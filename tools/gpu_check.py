"""Checks the CUDA path on a machine with an NVIDIA GPU in a few minutes (the first run
compiles the CUDA kernels): walks a dataset of a bent ball on the GPU, trains the proposed
variant 2,000 steps there (each batch moved from host memory), and renders one view with the
trained network (the Warp encoder inside the wave loop) on the GPU and on the CPU, again on
the GPU in waves split by a small wave cap, and again under a side ``torch.cuda.stream``;
each GPU render must match the CPU's: hits equal but at most one pixel, distances within
1e-5 where both hit. Prints the driver's, torch's and Warp's versions and the timings.

With ``--benchmark JSON`` it then measures the trained ball on the GPU (``benchmark``): a
1920x1080 frame's neural rays/s against Warp's BVH (refit to the bent ball + the same
casts), the frame's host reads and Warp kernel launches, the network alone from 2^16 to
2^22 segments in float32 and bfloat16, and each figure's share of the GPU's arithmetic and
memory peaks where the GPU is one of ``PEAKS``. An H200 has no ray-tracing cores: OptiX on
an RTX card is a stronger classical path, not measured here. The JSON is marked as the
benchmark's, checked by the output rule before anything else (the CUDA device included) and
written atomically: it replaces only a file the benchmark wrote.

    make gpu-check          (or: .venv/bin/python tools/gpu_check.py)
    .venv/bin/python tools/gpu_check.py --benchmark out/gpu-benchmark.json

Exit status 0 when every comparison holds, 1 when one fails or there is no CUDA device (one
line on stderr, before any work).
"""

import argparse
import copy
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402

MAX_HIT_DIFFERENCES = 1
"""Pixels whose hit may differ between the devices: a float32 MLP sums in another order on
a GPU, which can move a probability across the threshold."""
DISTANCE_TOLERANCE = 1e-5
"""Largest distance difference (object units) where both devices hit."""
SPLIT_WAVE = 1000
"""The wave cap of the split render: far below the view's segments, so that waves split."""
FRAME = (1920, 1080)
"""The benchmark's frame, pixels."""
SEGMENT_SWEEP = tuple(2 ** k for k in range(16, 23))
"""Batch sizes of the benchmark's network-alone figures."""
PEAKS = {
    # NVIDIA's H200 SXM data sheet: FP32 67 TFLOPS, BF16 tensor cores 989 TFLOPS dense,
    # HBM3e 4.8 TB/s; no RT cores.
    "H200": {"float32_flops": 67e12, "bfloat16_flops": 989e12, "bytes_per_s": 4.8e12},
}
"""Peak arithmetic (per precision) and memory bandwidth of GPUs by a part of their name."""
FORMAT = "vdnif-gpu-benchmark"
"""The benchmark's format mark: the output rule lets ``--benchmark`` replace only its own
file."""
VIEW = np.array([-0.5, 0.4, 1.0]) / np.linalg.norm([-0.5, 0.4, 1.0])
"""The rendered views' direction, onto the ball's bent side."""


def bent(points):
    """``points`` (N, 3) moved by the ball's smooth non-affine pose: x += 0.15 z^2."""
    moved = np.array(points, np.float64)
    moved[:, 0] += 0.15 * moved[:, 2] ** 2
    return moved


def peaks_of(gpu: str) -> dict | None:
    """The ``PEAKS`` of the GPU named ``gpu`` (None where not known)."""
    return next((value for part, value in PEAKS.items() if part in gpu), None)


def cuda_problem() -> str | None:
    """Why this machine cannot run the check (None when it can): torch and Warp must both
    see a CUDA device."""
    import torch

    if not torch.cuda.is_available():
        return f"torch {torch.__version__} sees no CUDA device"
    from vdnif_addon.kernels import runtime

    if runtime.cuda_device_count() == 0:
        return (f"Warp {runtime.warp_version()} sees no CUDA device (it needs an NVIDIA "
                "driver for CUDA 13 and a Turing or newer GPU)")
    return None


def versions() -> dict[str, str]:
    """The GPU, the driver (its release as nvidia-smi gives it, and its CUDA version),
    torch's and Warp's versions with the CUDA each was built with."""
    import torch

    from vdnif_addon.kernels import runtime

    wp = runtime.init()
    try:
        release = subprocess.run(["nvidia-smi", "--query-gpu=driver_version",
                                  "--format=csv,noheader"], capture_output=True, text=True,
                                 timeout=30).stdout.splitlines()[0].strip()
    except (OSError, IndexError, subprocess.SubprocessError):
        release = "?"
    cuda = wp.get_cuda_driver_version()
    toolkit = wp.get_cuda_toolkit_version()
    return {"gpu": torch.cuda.get_device_name(0),
            "driver": f"{release} (CUDA {'.'.join(map(str, cuda)) if cuda else '?'})",
            "torch": f"{torch.__version__} (CUDA {torch.version.cuda})",
            "warp": f"{wp.__version__} (CUDA {'.'.join(map(str, toolkit)) if toolkit else '?'})"}


def ball(resolution: int = 12, rings: int = 24, sides: int = 32):
    """(RestMesh, VoxelGrid, bent corners): a UV sphere of two materials, its grid and a smooth
    non-affine pose of the grid's corners."""
    from vdnif_addon.geometry import voxels
    from vdnif_addon.geometry.restmesh import Albedo, RestMesh

    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([np.outer(np.sin(theta), np.cos(phi)), np.outer(np.sin(theta), np.sin(phi)),
                     np.outer(np.cos(theta), np.ones(sides))], -1).reshape(-1, 3)
    vertices = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]).astype(np.float64)
    triangles = []
    for s in range(sides):
        t = (s + 1) % sides
        triangles.append((0, 1 + s, 1 + t))
        for r in range(rings - 2):
            a, b = 1 + r * sides, 1 + (r + 1) * sides
            triangles += [(a + s, b + s, b + t), (a + s, b + t, a + t)]
        last = 1 + (rings - 2) * sides
        triangles.append((last + s, len(vertices) - 1, last + t))
    triangles = np.array(triangles, np.int32)
    normals = vertices[triangles].astype(np.float32)
    material = (vertices[triangles].mean(1)[:, 2] > 0).astype(np.int32)
    albedo = [Albedo("constant", np.array(c, np.float32)) for c in ((1, 0, 0), (0, 0, 1))]
    mesh = RestMesh(name="Ball", vertices=vertices, triangles=triangles, corner_normals=normals,
                    material_index=material, albedo=albedo)
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, resolution)
    return mesh, grid, bent(grid.corner_positions())


def dataset(mesh, grid, bend, poses: int, rays_per_pose: int, device: str):
    """(shards, DatasetHeader): ``poses`` poses between the rest pose and ``bend``, each
    walked and labelled on ``device``."""
    from vdnif_addon.geometry.attributes import sample_surface
    from vdnif_addon.kernels.cells import DeviceCells
    from vdnif_addon.tracing import groundtruth, rays
    from vdnif_addon.tracing.traverse import traverse
    from vdnif_addon.training import dataset as data
    from vdnif_addon.training.header import FORMAT, VERSION, DatasetHeader

    rest = grid.corner_positions()
    caster = groundtruth.rest_surface(mesh, grid, device)
    shards, segments = [], 0
    for pose in range(poses):
        corners = rest + (bend - rest) * (pose / max(poses - 1, 1))
        rng = np.random.default_rng(pose)
        surface, _, _ = sample_surface(mesh.vertices, mesh.triangles, rays_per_pose, rng)
        origins, directions = rays.training_rays(corners.min(0), corners.max(0), surface,
                                                 rays_per_pose, 0.5, rng)
        walked = traverse(DeviceCells(grid, device, corners=corners), origins, directions)
        targets = groundtruth.segment_targets(mesh, caster, walked)
        shards.append(data.segment_records(grid, walked, targets, pose))
        segments += len(walked)
    header = DatasetHeader.from_dict({
        "format": FORMAT, "version": VERSION, "object": mesh.name, "mode": "armature",
        "object_size": mesh.size, "grid": data.grid_header(grid, mesh).to_dict(),
        "voxel_size": grid.voxel_size, "heads": mesh.heads(),
        "albedo_table": mesh.albedo_table().tolist(),
        "poses": [{"frame": float(p)} for p in range(poses)], "pose_range": [0, poses],
        "seed": 0, "rays_per_pose": rays_per_pose, "surface_fraction": 0.5,
        "grazing_fraction": 0.0, "inverted_cells": [0] * poses,
        "counts": {"rays": poses * rays_per_pose, "segments": segments,
                   "hits": int(sum(s["hit"].sum() for s in shards))},
        "timings": {"total_s": 0.0}, "versions": {"vdnif": "gpu-check"}, "segments": segments,
    }, "gpu-check dataset")
    return shards, header


def compare(cpu, gpu) -> tuple[int, float]:
    """(pixels whose hit differs, largest distance difference where both hit)."""
    both = cpu.hit & gpu.hit
    distance = float(np.abs(cpu.distance - gpu.distance)[both].max()) if both.any() else 0.0
    return int((cpu.hit != gpu.hit).sum()), distance


def check(steps: int = 2000, size: int = 128, poses: int = 6, rays_per_pose: int = 16384,
          say=print, trained: list | None = None) -> bool:
    """Trains and renders as the module says; reports through ``say``; True when every
    GPU render matches the CPU's. The trained network is appended to ``trained``."""
    import torch

    from vdnif_addon.inference.neural_render import neural_passes
    from vdnif_addon.kernels.cells import DeviceCells
    from vdnif_addon.model.variants import variant_config
    from vdnif_addon.tracing import rays
    from vdnif_addon.training.train import train

    for name, version in versions().items():
        say(f"{name}: {version}")
    mesh, grid, bend = ball()
    clock = time.perf_counter()
    shards, header = dataset(mesh, grid, bend, poses, rays_per_pose, "cuda:0")
    say(f"dataset on cuda:0: {header.segments} segments of {poses} poses in "
        f"{time.perf_counter() - clock:.1f} s")
    chosen = variant_config("proposed", steps=steps, batch_size=8192, device="cuda",
                            log_interval=steps)
    result = train(shards, header, chosen.train, chosen.network)
    say(f"training on cuda:0: {result.steps} steps in {result.seconds:.1f} s, "
        f"{result.samples_per_s:,.0f} segments/s, validation {result.validation}")
    network = result.network
    if trained is not None:
        trained.append(network)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), VIEW, size, size)
    table = mesh.albedo_table()

    def render(device, net, **options):
        cells = DeviceCells(grid, "cuda:0" if device == "cuda" else "cpu", corners=bend)
        clock = time.perf_counter()
        passes, stats = neural_passes(net, grid, table, cells, origins, directions,
                                      device=device, **options)
        return passes, stats, time.perf_counter() - clock

    cpu, cpu_stats, cpu_s = render("cpu", copy.deepcopy(network).cpu())
    say(f"render on the CPU: {size}x{size}, {cpu.hit.sum()} hits, {cpu_stats['waves']} waves, "
        f"{cpu_s:.2f} s")
    ok = cpu.hit.sum() > 0
    runs = {"cuda": {}, "cuda, waves split": {"max_wave_segments": SPLIT_WAVE}}
    for label, options in [*runs.items(), ("cuda, side stream", None)]:
        if options is None:
            with torch.cuda.stream(torch.cuda.Stream()):
                gpu, stats, seconds = render("cuda", network)
        else:
            render("cuda", network, **options)        # the first also compiles the kernels
            gpu, stats, seconds = render("cuda", network, **options)
        hits, distance = compare(cpu, gpu)
        good = (hits <= MAX_HIT_DIFFERENCES and distance <= DISTANCE_TOLERANCE
                and stats["truncated"] == 0)
        ok &= good
        say(f"render on {label}: {stats['waves']} waves, {seconds:.3f} s; against the CPU: "
            f"{hits} hits differ (at most {MAX_HIT_DIFFERENCES}), distances within "
            f"{distance:.2e} (at most {DISTANCE_TOLERANCE:.0e}): {'ok' if good else 'FAILED'}")
    return bool(ok)


def _median_s(run, repeats: int, synchronize) -> float:
    """Median seconds of ``repeats`` runs of ``run`` after one warm-up run."""
    import statistics

    run()
    times = []
    for _ in range(repeats):
        synchronize()
        clock = time.perf_counter()
        run()
        synchronize()
        times.append(time.perf_counter() - clock)
    return statistics.median(times)


def network_cost(network) -> dict[str, float]:
    """Per segment: multiply-adds of the segment MLP and heads (the Linear layers outside
    the point fields, which run at candidate hits only) and bytes of hash-table rows the
    segment encoder reads (8 corners a level at each of its 2 (1 + 2F) points)."""
    import torch

    fields = [m for m in (getattr(network, "albedo_field", None),
                          getattr(network, "normal_field", None)) if m is not None]
    in_fields = {id(m) for field in fields for m in field.modules()}
    macs = sum(m.in_features * m.out_features for m in network.modules()
               if isinstance(m, torch.nn.Linear) and id(m) not in in_fields)
    encoder = network.encoder
    grid = encoder.grid
    points = 2 * (1 + 2 * encoder.pe_bands)
    reads = points * grid.levels * 8
    return {"macs": float(macs), "table_reads": float(reads),
            "table_bytes": float(reads * grid.feature_dim * grid.table.element_size())}


def roofline(segments_per_s: float, cost: dict, precision: str, gpu: str) -> dict | None:
    """Achieved FLOP/s and table bytes/s at ``segments_per_s`` and their shares of the
    peaks of ``gpu`` (None where ``PEAKS`` does not know it)."""
    peaks = peaks_of(gpu)
    flops = 2 * cost["macs"] * segments_per_s
    moved = cost["table_bytes"] * segments_per_s
    figures = {"flops": flops, "table_bytes_per_s": moved}
    if peaks is None:
        return dict(figures, share_of_flops=None, share_of_bandwidth=None)
    return dict(figures, share_of_flops=flops / peaks[f"{precision}_flops"],
                share_of_bandwidth=moved / peaks["bytes_per_s"])


def benchmark(network, mesh, grid, bend, device: str = "cuda", frame=FRAME,
              sweep=SEGMENT_SWEEP, repeats: int = 3, say=print) -> dict:
    """The benchmark of the module's docstring on ``device`` with the trained ``network``
    of the ball (``mesh``, ``grid``, its ``bend``): a JSON-ready dict."""
    import torch
    import warp as wp

    sys.path.insert(0, str(ROOT / "tests" / "support"))
    from host_reads import counting_host_reads

    from vdnif_addon.inference.neural_render import neural_passes
    from vdnif_addon.kernels import runtime
    from vdnif_addon.kernels.cast import MeshCaster
    from vdnif_addon.kernels.cells import DeviceCells
    from vdnif_addon.tracing import rays

    warp_device = "cuda:0" if device == "cuda" else "cpu"
    torch_device = torch.device(device)
    gpu = torch.cuda.get_device_name(0) if device == "cuda" else "cpu"

    def synchronize():
        runtime.init().synchronize_device(warp_device)
        if device == "cuda":
            torch.cuda.synchronize()

    width, height = frame
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), VIEW, width, height)
    table = mesh.albedo_table()
    network = network.to(torch_device).eval()
    cells = DeviceCells(grid, warp_device, corners=bend)

    def render():
        return neural_passes(network, grid, table, cells, origins, directions, device=device)

    render_s = _median_s(render, repeats, synchronize)
    launches, launch = [], wp.launch

    def counted_launch(*args, **kwargs):
        launches.append(getattr(args[0], "key", "kernel"))
        return launch(*args, **kwargs)

    wp.launch = counted_launch
    try:
        with counting_host_reads() as reads:
            passes, stats = render()
    finally:
        wp.launch = launch
    # Warp's BVH over the ball bent as its corners are, refit and cast
    posed = bent(mesh.vertices)
    caster = MeshCaster(mesh.vertices, mesh.triangles, warp_device)
    refit_s = _median_s(lambda: caster.refit(posed), repeats, synchronize)
    cast_s = _median_s(lambda: caster.cast(origins, directions, np.inf), repeats, synchronize)
    frame_figures = {
        "width": width, "height": height, "rays": len(origins), "hits": int(passes.hit.sum()),
        "waves": stats["waves"], "segments": stats["segments"], "render_s": render_s,
        "neural_rays_per_s": len(origins) / render_s, "host_reads": len(reads),
        "warp_launches": len(launches), "warp_refit_s": refit_s, "warp_cast_s": cast_s,
        "warp_rays_per_s": len(origins) / (refit_s + cast_s)}
    say(f"benchmark {width}x{height} on {gpu}: neural {frame_figures['neural_rays_per_s']:,.0f} "
        f"rays/s ({render_s * 1e3:.1f} ms, {stats['waves']} waves, {len(reads)} host reads, "
        f"{len(launches)} Warp launches); Warp BVH refit + casts "
        f"{frame_figures['warp_rays_per_s']:,.0f} rays/s ({refit_s * 1e3:.2f} + "
        f"{cast_s * 1e3:.1f} ms)")
    cost = network_cost(network)
    sweeps = []
    generator = torch.Generator().manual_seed(0)
    low, high = (torch.as_tensor(v, dtype=torch.float32) for v in (bend.min(0), bend.max(0)))
    precisions = ["float32"] + (["bfloat16"] if runtime.bfloat16_native(torch_device) else [])
    for precision in precisions:
        network.precision = precision
        for count in sweep:
            p0, p1 = (low + (high - low) * torch.rand(count, 3, generator=generator)
                      for _ in range(2))
            p0, p1 = p0.to(torch_device), p1.to(torch_device)
            rest = torch.full((count,), grid.voxel_size, device=torch_device)
            seconds = _median_s(lambda p0=p0, p1=p1, rest=rest, count=count: network.predict(
                p0, p1, rest, grid.voxel_size, batch=count), repeats, synchronize)
            row = {"precision": precision, "segments": count,
                   "segments_per_s": count / seconds,
                   **roofline(count / seconds, cost, precision, gpu)}
            sweeps.append(row)
            share = row["share_of_bandwidth"]
            say(f"network alone, {precision}, {count:,} segments: "
                f"{row['segments_per_s']:,.0f} segments/s"
                + ("" if share is None else f" ({share:.1%} of the memory peak, "
                   f"{row['share_of_flops']:.1%} of the arithmetic peak)"))
    network.precision = "float32"
    return {"device": gpu, "frame": frame_figures, "network_cost": cost, "network": sweeps,
            "peaks": peaks_of(gpu),
            "note": "an H200 has no ray-tracing cores: OptiX on an RTX card is a stronger "
                    "classical path, not measured here"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=2000, help="training steps on the GPU")
    parser.add_argument("--size", type=int, default=128, help="rendered view's side, pixels")
    parser.add_argument("--benchmark", type=pathlib.Path, metavar="JSON",
                        help="then benchmark the trained ball on the GPU into this file")
    args = parser.parse_args(argv)
    from vdnif_addon.safe_io import check_output_file, write_json_atomic

    trained = []
    try:
        if args.benchmark is not None:      # the output rule, before the device and any work
            check_output_file(args.benchmark, "--benchmark", "json")
        problem = cuda_problem()
        if problem is not None:
            raise VDNIFError(f"no CUDA device to check: {problem}")
        ok = check(args.steps, args.size, trained=trained)
        if ok and args.benchmark is not None:
            from vdnif_addon.model.provenance import stamp

            figures = stamp({"format": FORMAT, **benchmark(trained[0], *ball()),
                             "versions": versions()})
            write_json_atomic(args.benchmark, figures, "--benchmark", indent=1)
    except VDNIFError as exc:
        print(f"gpu_check: error: {exc}", file=sys.stderr)
        return 1
    print("gpu-check: " + ("passed" if ok else "FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
