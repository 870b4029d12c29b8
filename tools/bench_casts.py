"""Ground-truth and true-reference casts: Warp kernels against Blender's BVHTree, alternately
in one process, on the same walked segments and rays.

    python tools/bench_casts.py --scene arm --resolution 32 --poses 4 --rays 4096 --repeats 3
    python tools/bench_casts.py --scene bunny --resolution 32 --poses 4 --view 256 --repeats 3

Segments come from today's walk of training rays (``--rays`` per pose, as ``dataset`` makes
them) or of an orbit view (``--view`` pixels square, as ``references`` does). Per repeat, each
path runs once over all poses; prints the medians of the repeats (seconds, rates) and the
medians of the per-repeat ratios. ``kernel_truth_whole_mesh`` casts the same segments from
the root of a BVH of the whole rest mesh instead of their cells' subtrees. The BVHTree path
is the pipeline before the kernels (``tests/oracles/surface_casts.py``): a Python loop over
``BVHTree.ray_cast``, weights and normals in numpy; its true reference builds a BVHTree per
pose, as it did.

``--json PATH`` writes the figures there, stamped with this checkout's provenance and marked as
the benchmark's: checked by the output rule before any scene is built, it replaces only a file
the benchmark wrote.
"""

import argparse
import json
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import bpy  # noqa: E402,F401  (before mathutils)
import numpy as np  # noqa: E402
import torch  # noqa: E402
from oracles import surface_casts as oracle  # noqa: E402

from vdnif_addon.blender.bvh import BVHCaster  # noqa: E402
from vdnif_addon.blender.capture_scene import capture  # noqa: E402
from vdnif_addon.blender.scenes import demo_scene  # noqa: E402
from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.geometry.attributes import sample_surface  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.pose_sets import PoseSpec  # noqa: E402
from vdnif_addon.posed.geometry import PosedObject  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402
from vdnif_addon.tracing import groundtruth, references  # noqa: E402
from vdnif_addon.tracing.rays import orbit_rays, orbit_viewpoints, training_rays  # noqa: E402
from vdnif_addon.tracing.traverse import traverse  # noqa: E402

FORMAT = "vdnif-bench-casts"
"""The figures' format mark: the output rule lets ``--json`` replace only the tool's own file."""


def poses_of(args):
    """The capture and per pose: segments, rays, deformed vertices and normals."""
    obj = demo_scene(args.scene)
    captured = capture(obj, args.resolution, PoseSpec(count=args.poses, seed=args.seed),
                       deform_corners=False)
    views = orbit_viewpoints(args.poses)
    inputs = []
    with PosedObject(obj, captured) as posed_object:
        for index, pose in enumerate(captured.poses):
            geometry = posed_object.geometry(pose)
            lo, hi = geometry.vertices.min(0), geometry.vertices.max(0)
            if args.view:
                origins, directions = orbit_rays(lo, hi, views[index], args.view, args.view)
            else:
                rng = np.random.default_rng([args.seed, index])
                surface, _, _ = sample_surface(geometry.vertices, captured.mesh.triangles,
                                               args.rays, rng)
                origins, directions = training_rays(lo, hi, surface, args.rays, 0.6, rng)
            segments = traverse(geometry.cells, origins, directions)
            inputs.append((segments, origins, directions, geometry.vertices, geometry.normals))
    return captured, inputs


def timed(function):
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="arm")
    parser.add_argument("--resolution", type=int, default=32)
    parser.add_argument("--poses", type=int, default=4)
    parser.add_argument("--rays", type=int, default=4096, help="training rays per pose")
    parser.add_argument("--view", type=int, default=0, help="orbit view size instead")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=pathlib.Path)
    args = parser.parse_args(argv)
    if args.json:
        check_output_file(args.json, "--json", "json")     # the output rule, before any work
    captured, inputs = poses_of(args)
    mesh = captured.mesh
    build_start = time.perf_counter()
    rest = groundtruth.rest_surface(mesh, captured.grid)
    build_s = time.perf_counter() - build_start
    tree = BVHCaster(mesh.vertices, mesh.triangles)
    deformed = groundtruth.rest_surface(mesh)
    whole = groundtruth.rest_surface(mesh)

    def kernel_truth():
        for segments, *_ in inputs:
            groundtruth.segment_targets(mesh, rest, segments)

    def kernel_truth_whole_mesh():
        for segments, *_ in inputs:
            groundtruth.segment_targets(mesh, whole, segments)

    def tree_truth():
        for segments, *_ in inputs:
            oracle.segment_targets(mesh, tree, segments)

    def kernel_reference():
        for _, origins, directions, vertices, normals in inputs:
            deformed.refit(vertices, normals)
            references.true_reference(mesh, deformed, origins, directions)

    def tree_reference():
        for _, origins, directions, vertices, normals in inputs:
            oracle.cast_surface(mesh, BVHCaster(vertices, mesh.triangles), origins, directions,
                                np.full(len(origins), np.inf), vertices, normals)

    paths = {"kernel_truth": kernel_truth, "kernel_truth_whole_mesh": kernel_truth_whole_mesh,
             "tree_truth": tree_truth, "kernel_reference": kernel_reference,
             "tree_reference": tree_reference}
    runs = {name: [] for name in paths}
    kernel_truth(), kernel_truth_whole_mesh(), kernel_reference()   # loads, first touches
    for _ in range(args.repeats):
        for name, function in paths.items():
            runs[name].append(timed(function))
    segments = sum(len(s) for s, *_ in inputs)
    rays = sum(len(o) for _, o, *_ in inputs)
    report = {
        "format": FORMAT, "scene": args.scene, "resolution": args.resolution, "poses": args.poses,
        "rays": rays, "segments": segments, "triangles": int(len(mesh.triangles)),
        "repeats": args.repeats, "torch_threads": torch.get_num_threads(),
        "rest_surface_build_s": build_s,
        "median_s": {name: statistics.median(v) for name, v in runs.items()},
        "segments_per_s": {name: segments / statistics.median(runs[name])
                           for name in ("kernel_truth", "kernel_truth_whole_mesh",
                                        "tree_truth")},
        "rays_per_s": {name: rays / statistics.median(runs[name])
                       for name in ("kernel_reference", "tree_reference")},
        "speedup": {kind: statistics.median(t / k for t, k in zip(runs[f"tree_{kind}"],
                                                                   runs[f"kernel_{kind}"]))
                    for kind in ("truth", "reference")},
        "cell_subtrees_speedup": statistics.median(
            w / k for w, k in zip(runs["kernel_truth_whole_mesh"], runs["kernel_truth"])),
    }
    report = stamp(report, with_machine=True)
    print(json.dumps(report, indent=1))
    if args.json:
        write_json_atomic(args.json, report, "--json", indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="bench_casts: error: ")
