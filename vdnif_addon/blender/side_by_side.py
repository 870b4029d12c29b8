"""Side by side with the classical path (DESIGN section 10, speed and size).

Per pose, the classical path re-evaluates the deformed mesh and rebuilds its BVHTree, then
casts every ray against it; the neural path deforms the voxel corners and refits the entry BVH
over the deformed cells, then renders with the network. On the rest pose, the deformation-aware
walk (entry BVH + face intersections) is timed against the static DDA walk of the same rays,
the paper's "2-3 % overhead": both are Warp kernels with the same segment buffers and
launches. Every figure is timed alternately in one process after one untimed pass, and
reported as the median over repeats, so background load affects both sides alike.
"""

import dataclasses
import io
import pathlib
import statistics
import time

import bpy
import numpy as np
import torch
from mathutils.bvhtree import BVHTree

from ..dda import StaticGrid
from ..errors import VDNIFError
from ..kernels import runtime
from ..network import Heads, IntersectionNetwork, NetworkConfig
from ..rays import orbit_rays, orbit_viewpoints
from ..render import predict_segments, neural_passes
from ..traverse import traverse
from .bvh import BVHCaster
from .posed import PosedObject
from .poses import posed

MILLION_SUBDIVISIONS = 5     # Suzanne (968 triangles) at level 5: 1,007,616 triangles
SCENES = ("bunny", "million", "arm", "lattice", "spot")

# Blender's BVHTree (BLI_kdopbvh, as mathutils builds it: 4 children, 6-axis bounds): per
# node a 32-byte BVHNode, 6 floats of bounds, 4 child pointers and 1 node pointer.
BVH_TREE_TYPE = 4
BVH_NODE_BYTES = 32 + 6 * 4 + BVH_TREE_TYPE * 8 + 8


def million_scene():
    """The ~1 M-triangle test mesh: the lattice demo's Suzanne subdivided 5 times (applied),
    with the procedural lattice rig, in an emptied file."""
    from .scenes import add_rig

    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.active_object
    obj.name = "Suzanne million"
    subdivision = obj.modifiers.new("Subdivision", "SUBSURF")
    subdivision.levels = MILLION_SUBDIVISIONS
    bpy.ops.object.modifier_apply(modifier=subdivision.name)
    return add_rig(obj, "lattice")


def load_side_by_side_scene(name):
    """The mesh object of a scene name in ``SCENES``."""
    from .scenes import demo_scene

    if name not in SCENES:
        raise VDNIFError(f"unknown scene '{name}': choose one of {', '.join(SCENES)}")
    return million_scene() if name == "million" else demo_scene(name)


def compare_paths(obj, capture, model, width, height, repeats, progress=None):
    """Times the classical and the neural path on every pose of ``capture`` of ``obj``.

    ``model`` is a ``neural.SceneModel``, or None for a freshly initialized network of the
    paper's configuration (timing only). Rays are an orbit camera per pose, ``width`` x
    ``height``, in the object's local space. Returns a JSON-ready dict: per-repeat records,
    their medians and the ratios (median over repeats of each repeat's ratio).
    """
    if repeats < 1:
        raise VDNIFError(f"side by side of '{obj.name}': repeats {repeats} must be at least 1")
    if width < 1 or height < 1:
        raise VDNIFError(f"side by side of '{obj.name}': image size {width}x{height} must be "
                         "at least 1x1")
    network, albedo_table, device, model_info = _network(capture, model)
    viewpoints = orbit_viewpoints(len(capture.poses))
    static_grid = StaticGrid(capture.grid, runtime.device(device))
    runs = []
    with PosedObject(obj, capture, device) as posed_object:
        rest = posed_object.rest_geometry()
        rest_rays = [orbit_rays(capture.mesh.vertices.min(0), capture.mesh.vertices.max(0),
                                view, width, height) for view in viewpoints]
        # one untimed pass: kernels load (or compile, the first time on a machine) and
        # torch sets itself up on first use, which no pose should be charged with
        _pose_record(obj, posed_object, capture.poses[0], viewpoints[0], width, height,
                     network, albedo_table, device)
        _rest_record(rest, static_grid, network, capture.grid, device, *rest_rays[0])
        for repeat in range(repeats):
            poses = [_pose_record(obj, posed_object, pose, view, width, height, network,
                                  albedo_table, device)
                     for pose, view in zip(capture.poses, viewpoints)]
            rest_views = [_rest_record(rest, static_grid, network, capture.grid, device, *rays)
                          for rays in rest_rays]
            runs.append({"poses": poses, "rest": rest_views})
            if progress is not None:
                progress(repeat + 1, repeats)
    mesh = capture.mesh
    sizes = _bytes(mesh, model_info.pop("bytes"))
    medians = {key: statistics.median(_mean(run, key) for run in runs)
               for key in (*runs[0]["poses"][0], *runs[0]["rest"][0])
               if key.endswith("_s") or key.endswith("segments") or key.endswith("hits")}
    return {
        "object": obj.name, "triangles": int(len(mesh.triangles)),
        "vertices": int(len(mesh.vertices)), "mode": capture.mode,
        "resolution": capture.grid.resolution,
        "occupied_voxels": int(len(capture.grid.cells)), "poses": len(capture.poses),
        "width": width, "height": height, "rays": width * height, "repeats": repeats,
        "network": model_info, "torch_threads": torch.get_num_threads(),
        "median": medians,
        "ratios": {name: statistics.median(_ratio(run, name) for run in runs)
                   for name in RATIOS},
        "ratio_runs": {name: [_ratio(run, name) for run in runs] for name in RATIOS},
        "segments_match": all(v["segments_match"] for run in runs for v in run["rest"]),
        "bytes": sizes,
        "runs": runs,
    }


class _TreeCaster(BVHCaster):
    """``BVHCaster.cast`` over a tree built elsewhere (``BVHTree.FromObject``)."""

    def __init__(self, tree):
        self.tree = tree


def _network(capture, model):
    """(network, albedo table, device, JSON description with the model's bytes)."""
    if model is not None:
        return model.network, model.albedo_table, model.device, {
            "trained": True, "model": model.path, "variant": model.variant,
            "device": str(model.device), "bytes": pathlib.Path(model.path).stat().st_size,
            "bytes_source": "model file"}
    config = dataclasses.replace(NetworkConfig(), heads=Heads.from_header(capture.mesh.heads()))
    with torch.random.fork_rng():
        torch.manual_seed(0)
        network = IntersectionNetwork(config).eval()
    buffer = io.BytesIO()
    torch.save(network.state_dict(), buffer)
    return network, capture.mesh.albedo_table(), torch.device("cpu"), {
        "trained": False, "model": None, "variant": "untrained, paper config",
        "device": "cpu", "bytes": len(buffer.getvalue()),
        "bytes_source": "serialized state_dict"}


def _pose_record(obj, posed_object, pose, view, width, height, network, albedo_table, device):
    """Seconds of both paths for one pose, each side's own Blender evaluation included."""
    geometry = posed_object.geometry(pose)          # read corners + refit: prepare_s
    origins, directions = orbit_rays(geometry.vertices.min(0), geometry.vertices.max(0),
                                     view, width, height)
    with posed(pose):
        classical_evaluate_s = _evaluation_s(obj)
        start = time.perf_counter()
        tree = BVHTree.FromObject(obj, bpy.context.evaluated_depsgraph_get())
        classical_bvh_s = time.perf_counter() - start
        deformer = posed_object.deformer
        neural_evaluate_s = 0.0 if deformer is None else _evaluation_s(deformer.helper)
    start = time.perf_counter()
    index, _ = _TreeCaster(tree).cast(origins, directions, np.full(len(origins), np.inf))
    classical_render_s = time.perf_counter() - start
    start = time.perf_counter()
    passes, stats = neural_passes(network, posed_object.capture.grid, albedo_table,
                                  geometry.cells, origins, directions, device)
    neural_render_s = time.perf_counter() - start
    return {
        "classical_evaluate_s": classical_evaluate_s, "classical_bvh_s": classical_bvh_s,
        "classical_rebuild_s": classical_evaluate_s + classical_bvh_s,
        "classical_render_s": classical_render_s, "classical_hits": int((index >= 0).sum()),
        "neural_evaluate_s": neural_evaluate_s, "neural_prepare_s": geometry.prepare_s,
        "neural_pose_s": neural_evaluate_s + geometry.prepare_s,
        "neural_render_s": neural_render_s, "neural_walk_s": stats["walk_s"],
        "neural_network_s": stats["network_s"], "neural_segments": stats["segments"],
        "neural_hits": int(passes.hit.sum()),
    }


def _evaluation_s(obj):
    """Seconds Blender takes to re-evaluate ``obj``'s modifiers in the current pose (the
    pose was evaluated once on entering it; tagging the object makes the depsgraph redo
    exactly its own stack)."""
    obj.update_tag(refresh={"DATA"})
    start = time.perf_counter()
    bpy.context.evaluated_depsgraph_get()
    return time.perf_counter() - start


def _rest_record(rest, static_grid, network, grid, device, origins, directions):
    """Deformed walk vs static DDA walk of the same rest-pose rays, and the network over
    every walked segment (the same segments for both walks)."""
    start = time.perf_counter()
    deformed = traverse(rest.cells, origins, directions)
    deformed_walk_s = time.perf_counter() - start
    start = time.perf_counter()
    static = static_grid.traverse(origins, directions)
    static_walk_s = time.perf_counter() - start
    start = time.perf_counter()
    if len(static):
        predict_segments(network, grid, static, device)
    network_s = time.perf_counter() - start
    match = (len(deformed) == len(static) and np.array_equal(deformed.ray, static.ray)
             and np.array_equal(deformed.cell, static.cell))
    return {"deformed_walk_s": deformed_walk_s, "static_walk_s": static_walk_s,
            "all_segments_network_s": network_s, "walk_segments": len(static),
            "segments_match": bool(match)}


def _mean(run, key):
    records = run["poses"] if key in run["poses"][0] else run["rest"]
    return statistics.fmean(record[key] for record in records)


# name: (numerator keys, denominator keys), sums of per-pose / per-view means
RATIOS = {
    "prepare_neural_over_classical": (("neural_pose_s",), ("classical_rebuild_s",)),
    "render_neural_over_classical": (("neural_render_s",), ("classical_render_s",)),
    "pose_neural_over_classical": (("neural_pose_s", "neural_render_s"),
                                   ("classical_rebuild_s", "classical_render_s")),
    "walk_deformed_over_static": (("deformed_walk_s",), ("static_walk_s",)),
    "walk_and_network_deformed_over_static": (("deformed_walk_s", "all_segments_network_s"),
                                              ("static_walk_s", "all_segments_network_s")),
}


def _ratio(run, name):
    numerator, denominator = RATIOS[name]
    return (sum(_mean(run, key) for key in numerator)
            / sum(_mean(run, key) for key in denominator))


def _bytes(mesh, model_bytes):
    """Model bytes vs mesh (float32 vertices, int32 triangles) + BVH bytes. The BVH is
    counted from Blender's allocation in BLI_bvhtree_new (mathutils' tree type 4, 6 axes):
    T leaves + max(1, (T + 1) // 3) inner nodes + 4 spare, BVH_NODE_BYTES each."""
    triangles = len(mesh.triangles)
    mesh_bytes = 12 * len(mesh.vertices) + 12 * triangles
    nodes = triangles + max(1, (triangles + BVH_TREE_TYPE - 3) // (BVH_TREE_TYPE - 1)) \
        + BVH_TREE_TYPE
    bvh_bytes = nodes * BVH_NODE_BYTES
    return {"model": model_bytes, "mesh": mesh_bytes, "bvh_estimate": bvh_bytes,
            "mesh_and_bvh": mesh_bytes + bvh_bytes,
            "model_over_mesh_and_bvh": model_bytes / (mesh_bytes + bvh_bytes)}


def side_by_side_markdown(results):
    """Markdown tables of one or more ``compare_paths`` results, one column per scene."""
    heads = " | ".join(f"{r['object']} ({r['triangles']:,} triangles)" for r in results)
    rule = "|---" * (len(results) + 1) + "|"

    def row(label, values):
        return f"| {label} | " + " | ".join(values) + " |"

    def times(key):
        return [f"{1e3 * r['median'][key]:.1f}" for r in results]

    lines = ["Per pose (or rest view), milliseconds: mean over the poses of one repeat, "
             "median over repeats.", "", f"| step | {heads} |", rule]
    for label, key in TIME_ROWS:
        lines.append(row(label, times(key)))
    lines.append(row("walked segments (rest view)",
                     [f"{r['median']['walk_segments']:,.0f}" for r in results]))
    lines.append(row("segments the neural render evaluated (per pose)",
                     [f"{r['median']['neural_segments']:,.0f}" for r in results]))
    lines += ["", "Ratios, median over repeats of each repeat's ratio (per-repeat values in "
              "brackets); below 1 the neural path is cheaper.", "", f"| ratio | {heads} |",
              rule]
    for label, name in RATIO_ROWS:
        lines.append(row(label, [f"**{r['ratios'][name]:.3g}** ("
                                 + ", ".join(f"{v:.3g}" for v in r["ratio_runs"][name]) + ")"
                                 for r in results]))
    lines += ["", "Bytes.", "", f"| | {heads} |", rule]
    for label, key in (("model", "model"), ("mesh (float32 vertices + int32 triangles)",
                                            "mesh"),
                       ("BVH (estimate)", "bvh_estimate"), ("mesh + BVH", "mesh_and_bvh")):
        lines.append(row(label, [f"{r['bytes'][key]:,}" for r in results]))
    lines.append(row("model / (mesh + BVH)",
                     [f"**{r['bytes']['model_over_mesh_and_bvh']:.3g}**" for r in results]))
    lines += ["", "Settings.", "", f"| | {heads} |", rule]
    lines.append(row("network", [f"{r['network']['variant']} ({r['network']['bytes_source']})"
                                 for r in results]))
    lines.append(row("device, torch threads",
                     [f"{r['network']['device']}, {r['torch_threads']}" for r in results]))
    lines.append(row("resolution, occupied voxels",
                     [f"{r['resolution']}, {r['occupied_voxels']:,}" for r in results]))
    lines.append(row("poses x repeats, rays per view",
                     [f"{r['poses']} x {r['repeats']}, {r['width']}x{r['height']}"
                      for r in results]))
    lines.append(row("DDA and deformed walk give the same cells",
                     ["yes" if r["segments_match"] else "no" for r in results]))
    return "\n".join(lines) + "\n"


TIME_ROWS = (
    ("classical: evaluate the mesh's modifiers", "classical_evaluate_s"),
    ("classical: `BVHTree.FromObject`", "classical_bvh_s"),
    ("classical: ray casts (`BVHTree.ray_cast` loop)", "classical_render_s"),
    ("neural: evaluate the corner helper's modifiers", "neural_evaluate_s"),
    ("neural: read corners + refit cells and entry BVH (`prepare_s`)", "neural_prepare_s"),
    ("neural: render (walk + network)", "neural_render_s"),
    ("rest view: deformed walk (`traverse.traverse`)", "deformed_walk_s"),
    ("rest view: static DDA walk (`dda.StaticGrid`)", "static_walk_s"),
    ("rest view: network over every walked segment", "all_segments_network_s"),
)
RATIO_ROWS = (
    ("per-pose preparation: neural / classical rebuild", "prepare_neural_over_classical"),
    ("render: neural / classical ray casts", "render_neural_over_classical"),
    ("pose total (preparation + render): neural / classical",
     "pose_neural_over_classical"),
    ("walk: deformed / static DDA (rest pose)", "walk_deformed_over_static"),
    ("walk + network: deformed / static DDA (rest pose)",
     "walk_and_network_deformed_over_static"),
)


def cmd_side_by_side(args):
    """Time the neural path against Blender's BVHTree per pose, the deformed walk against
    a static DDA walk, and model bytes against mesh + BVH bytes."""
    from ..commands import check_resolution, write_json
    from ..progress import Progress
    from .capture import capture
    from .neural import load_scene_model
    from .poses import PoseSpec, evaluation_spec

    if args.model is not None and len(args.scene) > 1:
        raise VDNIFError("--model fits one scene: give a single --scene with it")
    check_resolution(args.resolution)
    results = []
    for name in args.scene:
        obj = load_side_by_side_scene(name)
        captured = capture(obj, args.resolution,
                           evaluation_spec(PoseSpec(count=args.poses, seed=args.seed)),
                           deform_corners=False)
        model = (None if args.model is None
                 else load_scene_model(args.model, captured, args.device))
        progress = Progress(f"side by side '{obj.name}'", args.repeats, "repeats")
        result = compare_paths(obj, captured, model, args.width, args.height, args.repeats,
                               progress=lambda done, _: progress.update(done))
        result["scene"] = name
        results.append(result)
        ratios = result["ratios"]
        print(f"side by side '{obj.name}' ({result['triangles']:,} triangles, "
              f"{result['network']['variant']}), medians of {args.repeats} repeats: "
              f"preparation {ratios['prepare_neural_over_classical']:.3g}x, render "
              f"{ratios['render_neural_over_classical']:.3g}x, pose total "
              f"{ratios['pose_neural_over_classical']:.3g}x the classical path; deformed "
              f"walk {ratios['walk_deformed_over_static']:.3g}x the static DDA walk; "
              f"model {result['bytes']['model_over_mesh_and_bvh']:.3g}x mesh + BVH bytes")
    write_json(args.json, results)
    if args.markdown is not None:
        path = pathlib.Path(args.markdown)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(side_by_side_markdown(results))
    return 0


def add_side_by_side_parser(commands):
    """Adds the ``side-by-side`` command to the batch parser's subcommands."""
    from ..commands import add_device_option

    parser = commands.add_parser("side-by-side", help=cmd_side_by_side.__doc__,
                                 description=cmd_side_by_side.__doc__ + (
                                     " Poses are unseen evaluation poses; 'million' is "
                                     "Suzanne subdivided to 1,007,616 triangles with a "
                                     "lattice rig."))
    parser.add_argument("--scene", nargs="+", choices=SCENES, default=["bunny"],
                        help="one or more scenes (default bunny)")
    parser.add_argument("--repeats", type=int, default=3, metavar="N",
                        help="timed repeats; medians are reported (default 3)")
    parser.add_argument("--model", type=pathlib.Path, metavar="MODEL", help=(
        "a model file trained on the scene (default: an untrained network of the paper's "
        "configuration, for timing only)"))
    parser.add_argument("--resolution", type=int, default=32, metavar="R",
                        help="voxel resolution (default 32; a model's must match)")
    parser.add_argument("--poses", type=int, default=4, metavar="N",
                        help="poses per repeat (default 4)")
    parser.add_argument("--seed", type=int, default=0,
                        help="training pose seed; the evaluation poses of it are used")
    parser.add_argument("--width", type=int, default=128, metavar="W")
    parser.add_argument("--height", type=int, default=128, metavar="H")
    add_device_option(parser, default="cpu")
    parser.add_argument("--json", type=pathlib.Path, metavar="PATH",
                        help="write every repeat's timings and the medians as JSON")
    parser.add_argument("--markdown", type=pathlib.Path, metavar="PATH",
                        help="write the tables for docs/performance.md")
    parser.set_defaults(run=cmd_side_by_side)
    return parser
