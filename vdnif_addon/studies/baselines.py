"""The classical baselines of ``side-by-side``: what a user who only wants first hits on a
deforming mesh runs per pose, each starting from Blender's evaluation of the pose (any
classical path needs the deformed vertices) and casting the same rays in the object's local
space. Each ``rebuild`` returns the pose's steps in seconds: ``evaluate_s`` (Blender's
evaluation of the deformed mesh), ``read_s`` (reading its vertices), ``build_s`` (the BVH's
refit or build); ``cast`` returns the first hits within a reach (``kernels.cast.MeshCaster``'s
interface: the hit triangle, BVHTree's hit polygon, and the distance); Warp's and Embree's
``vertices`` hold the pose's vertices once read; ``threads`` says on how many threads each
step ran at a run's thread setting; ``bvh_bytes`` how many bytes the acceleration structure
holds, and ``bytes_source`` how that was found.

- ``bvhtree``: Blender's own ``BVHTree`` rebuilt from the evaluated object
  (``BVHTree.FromObject``, on Blender's task threads), then a Python loop of ``ray_cast``
  (mathutils has no batch API, and the loop holds the GIL): one thread at any setting.
- ``warp``: Warp's mesh BVH over the rest triangles, built once; per pose the evaluated
  vertices are copied in and the BVH is ``refit``, then one kernel of ``mesh_query_ray``
  casts (``kernels.cast.MeshCaster``). Warp's CPU refit runs on one thread; the casts are
  split over the setting's threads, a launch each (a Warp CPU launch runs on one).
- ``embree_refit`` and ``embree_rebuild``: Embree, the CPU ray tracer inside Cycles, through
  its C API (``baselines_embree``): the evaluated vertices are read into the vertex array
  Embree shares, then the commit refits the BVH or builds a new one; packets of rays split
  over the setting's threads, which also build.
"""

import time

import bpy
import numpy as np
from mathutils.bvhtree import BVHTree

from ..blender.bvh import BVHCaster
from ..errors import VDNIFError
from ..kernels import runtime
from ..kernels.cast import MeshCaster
from .baselines_embree import EmbreeDevice, EmbreeScene

BASELINES = ("bvhtree", "warp", "embree_refit", "embree_rebuild")
BLENDER_THREADS = "Blender's"      # steps on Blender's own task threads, which bpy cannot set

# Blender's BVHTree (BLI_kdopbvh, as mathutils builds it: 4 children, 6-axis bounds): per
# node a 32-byte BVHNode, 6 floats of bounds, 4 child pointers and 1 node pointer.
BVH_TREE_TYPE = 4
BVH_NODE_BYTES = 32 + 6 * 4 + BVH_TREE_TYPE * 8 + 8


def evaluation_s(obj):
    """Seconds Blender takes to re-evaluate ``obj``'s modifiers in the current pose (the
    pose was evaluated once on entering it; tagging the object makes the depsgraph redo
    exactly its own stack)."""
    obj.update_tag(refresh={"DATA"})
    start = time.perf_counter()
    bpy.context.evaluated_depsgraph_get()
    return time.perf_counter() - start


def evaluated_vertices(obj, count, out=None):
    """(V, 3) float32 vertices of ``obj``'s evaluated mesh in its local space, read in one
    ``foreach_get`` (into ``out``, a (V, 3) view, where given); ``count`` is the rest mesh's
    vertex count, which deform modifiers keep."""
    mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    if len(mesh.vertices) != count:
        raise VDNIFError(f"'{obj.name}': a modifier changes the vertex count between rest "
                         f"({count}) and pose ({len(mesh.vertices)}); only deform modifiers "
                         "are supported")
    co = np.empty(3 * count, np.float32)
    mesh.vertices.foreach_get("co", co)
    if out is None:
        return co.reshape(-1, 3)
    out[:] = co.reshape(-1, 3)
    return out


class BVHTreeBaseline:
    """Blender's ``BVHTree`` rebuilt from the evaluated object every pose."""

    name = "bvhtree"
    bytes_source = ("estimate from Blender's allocation in BLI_bvhtree_new (tree type 4, "
                    "6 axes): T leaves + max(1, (T + 1) // 3) inner nodes + 4, 96 bytes each")

    def __init__(self, mesh):
        self.triangles = len(mesh.triangles)
        self.tree = None
        self.threads = {"build": BLENDER_THREADS, "casts": 1}

    def rebuild(self, obj):
        evaluate_s = evaluation_s(obj)
        start = time.perf_counter()
        self.tree = BVHTree.FromObject(obj, bpy.context.evaluated_depsgraph_get())
        return {"evaluate_s": evaluate_s, "build_s": time.perf_counter() - start}

    def cast(self, origins, directions, max_distance=np.inf):
        """(index (N,) int64, -1 on a miss; distance (N,) float64, inf on a miss)."""
        caster = BVHCaster.__new__(BVHCaster)
        caster.tree = self.tree
        return caster.cast(origins, directions, np.broadcast_to(
            np.asarray(max_distance, np.float64), (len(origins),)))

    def bvh_bytes(self):
        return bvhtree_bytes(self.triangles)

    def close(self):
        self.tree = None


def bvhtree_bytes(triangles):
    """Bytes of Blender's BVHTree over ``triangles`` triangles (``BVHTreeBaseline``)."""
    inner = max(1, (triangles + BVH_TREE_TYPE - 3) // (BVH_TREE_TYPE - 1))
    return (triangles + inner + BVH_TREE_TYPE) * BVH_NODE_BYTES


class WarpRefitBaseline:
    """Warp's mesh BVH over the rest triangles, refit to the evaluated vertices every pose,
    on Warp ``device``."""

    name = "warp"
    bytes_source = ("Warp 1.19's allocation (native/mesh.cpp, bvh.cpp): per triangle its "
                    "bounds (24 bytes, kept for refits) and a primitive index (4), and "
                    "2 T - 1 nodes of two 16-byte halves and a parent index (36 each)")

    def __init__(self, mesh, device="cpu", threads=1):
        self.vertex_count = len(mesh.vertices)
        self.triangles = len(mesh.triangles)
        self.device = runtime.device(device)
        self.caster = MeshCaster(mesh.vertices, mesh.triangles, self.device)
        self.vertices = None
        self.cast_threads = threads             # MeshCaster splits CPU casts only
        cpu = self.device == "cpu"
        self.threads = {"build": 1 if cpu else self.device,
                        "casts": threads if cpu else self.device}

    def rebuild(self, obj):
        evaluate_s = evaluation_s(obj)
        start = time.perf_counter()
        self.vertices = evaluated_vertices(obj, self.vertex_count)
        read_s = time.perf_counter() - start
        start = time.perf_counter()
        self.caster.refit(self.vertices)
        runtime.init().synchronize_device(self.device)
        return {"evaluate_s": evaluate_s, "read_s": read_s,
                "build_s": time.perf_counter() - start}

    def cast(self, origins, directions, max_distance=np.inf):
        return self.caster.cast(origins, directions, max_distance, self.cast_threads)

    def bvh_bytes(self):
        return warp_bvh_bytes(self.triangles)

    def close(self):
        self.caster = None


def warp_bvh_bytes(triangles):
    """Bytes Warp 1.19 allocates for a mesh BVH over ``triangles`` triangles beside the
    points and indices (``WarpRefitBaseline``)."""
    return (24 + 4) * triangles + 36 * (2 * triangles - 1) if triangles else 0


class EmbreeBaseline:
    """Embree's scene of the mesh on ``device`` (a ``baselines_embree.EmbreeDevice``), its
    vertices shared with Embree: each pose reads the evaluated vertices into them and
    commits, which refits the BVH (``refit``) or builds a new one."""

    bytes_source = ("measured: Embree's own memory monitor (rtcSetDeviceMemoryMonitorFunction) "
                    "over the build of the same scene (its vertex and index arrays are "
                    "shared, Embree allocates none for them); these are the bytes Embree "
                    "allocates, in the blocks its allocator takes, not the bytes its nodes fill")

    def __init__(self, mesh, device, refit):
        self.name = "embree_refit" if refit else "embree_rebuild"
        self.scene = EmbreeScene(device, mesh.vertices, mesh.triangles, refit)
        self.vertices = self.scene.vertices
        self.threads = {"build": device.threads, "casts": device.threads}

    def rebuild(self, obj):
        evaluate_s = evaluation_s(obj)
        start = time.perf_counter()
        evaluated_vertices(obj, self.scene.count, out=self.scene.vertices)
        read_s = time.perf_counter() - start
        start = time.perf_counter()
        self.scene.commit()
        return {"evaluate_s": evaluate_s, "read_s": read_s,
                "build_s": time.perf_counter() - start}

    def cast(self, origins, directions, max_distance=np.inf):
        return self.scene.cast(origins, directions, max_distance)

    def bvh_bytes(self):
        return self.scene.bvh_bytes()

    def close(self):
        self.scene.close()


def make_baselines(mesh, device="cpu", threads=1):
    """(every baseline of ``BASELINES`` for the rest ``mesh``, the Embree device they
    share): the Warp one on ``device`` (its CPU casts over ``threads`` threads), the Embree
    ones on an Embree device of ``threads`` threads. ``close_baselines`` releases them."""
    embree = EmbreeDevice(threads)
    made = []
    try:
        for make in (lambda: BVHTreeBaseline(mesh),
                     lambda: WarpRefitBaseline(mesh, device, threads),
                     lambda: EmbreeBaseline(mesh, embree, refit=True),
                     lambda: EmbreeBaseline(mesh, embree, refit=False)):
            made.append(make())
    except BaseException:
        close_baselines(made, embree)
        raise
    return made, embree


def close_baselines(baselines, embree):
    """Releases ``baselines``, then the Embree device their scenes live on."""
    for baseline in baselines:
        baseline.close()
    embree.close()
