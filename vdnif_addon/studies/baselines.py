"""The classical baselines of ``side-by-side``: what a user who only wants first hits on a
deforming mesh runs per pose, each starting from Blender's evaluation of the pose (any
classical path needs the deformed vertices) and casting the same rays in the object's local
space.

- ``BVHTreeBaseline``: Blender's own ``BVHTree`` rebuilt from the evaluated object
  (``BVHTree.FromObject``), then a Python loop of ``ray_cast`` (mathutils has no batch API),
  one core.
- ``WarpRefitBaseline``: Warp's mesh BVH over the rest triangles, built once; per pose the
  evaluated vertices are copied in and the BVH is ``refit`` (same triangles, no rebuild),
  then one kernel of ``mesh_query_ray`` casts (``kernels.cast.MeshCaster``). A Warp CPU
  launch runs on one thread.
- ``EmbreeBaseline``: Embree, the CPU ray tracer inside Cycles, through its PyPI binding
  ``embreex``: a scene rebuilt per pose (Embree has no refit for a static scene), robust
  traversal, Embree's default build quality; the rays are split over ``EMBREE_THREADS``
  threads since one ``run`` is a single-threaded loop (it releases the GIL). ``embreex`` is a
  benchmark dependency: it is imported here, lazily, and nowhere in the extension.

Each baseline's ``rebuild`` returns its named seconds (the caller sums them into the pose's
rebuild time) and ``cast`` its first hits; ``bvh_bytes`` says how many bytes its acceleration
structure holds, and how that was found.
"""

import ctypes
import glob
import os
import time
from concurrent.futures import ThreadPoolExecutor

import bpy
import numpy as np
from mathutils.bvhtree import BVHTree

from ..blender.bvh import BVHCaster
from ..errors import VDNIFError
from ..kernels import runtime
from ..kernels.cast import MeshCaster

EMBREE_THREADS = 2            # the casts of one pose, split over both cores of the machine
BASELINES = ("bvhtree", "warp", "embree")
# CPU threads each baseline's casts run on: a Python loop, one Warp CPU launch, Embree's runs.
THREADS = {"bvhtree": 1, "warp": 1, "embree": EMBREE_THREADS}

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


def evaluated_vertices(obj, count):
    """(V, 3) float32 vertices of ``obj``'s evaluated mesh in its local space, read in one
    ``foreach_get``; ``count`` is the rest mesh's vertex count, which deform modifiers keep."""
    mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    if len(mesh.vertices) != count:
        raise VDNIFError(f"'{obj.name}': a modifier changes the vertex count between rest "
                         f"({count}) and pose ({len(mesh.vertices)}); only deform modifiers "
                         "are supported")
    co = np.empty(3 * count, np.float32)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


class BVHTreeBaseline:
    """Blender's ``BVHTree`` rebuilt from the evaluated object every pose."""

    name = "bvhtree"
    bytes_source = ("estimate from Blender's allocation in BLI_bvhtree_new (tree type 4, "
                    "6 axes): T leaves + max(1, (T + 1) // 3) inner nodes + 4, 96 bytes each")

    def __init__(self, mesh):
        self.triangles = len(mesh.triangles)
        self.tree = None

    def rebuild(self, obj):
        evaluate_s = evaluation_s(obj)
        start = time.perf_counter()
        self.tree = BVHTree.FromObject(obj, bpy.context.evaluated_depsgraph_get())
        return {"evaluate_s": evaluate_s, "build_s": time.perf_counter() - start}

    def cast(self, origins, directions):
        """(hit (N,) bool, distance (N,) float64, inf on a miss)."""
        caster = BVHCaster.__new__(BVHCaster)
        caster.tree = self.tree
        index, t = caster.cast(origins, directions, np.full(len(origins), np.inf))
        return index >= 0, t

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

    def __init__(self, mesh, device="cpu"):
        self.vertex_count = len(mesh.vertices)
        self.triangles = len(mesh.triangles)
        self.device = runtime.device(device)
        self.caster = MeshCaster(mesh.vertices, mesh.triangles, self.device)

    def rebuild(self, obj):
        evaluate_s = evaluation_s(obj)
        start = time.perf_counter()
        vertices = evaluated_vertices(obj, self.vertex_count)
        read_s = time.perf_counter() - start
        start = time.perf_counter()
        self.caster.refit(vertices)
        runtime.init().synchronize_device(self.device)
        return {"evaluate_s": evaluate_s, "read_s": read_s,
                "refit_s": time.perf_counter() - start}

    def cast(self, origins, directions):
        index, t = self.caster.cast(origins, directions, np.inf)
        return index >= 0, t

    def bvh_bytes(self):
        return warp_bvh_bytes(self.triangles)

    def close(self):
        self.caster = None


def warp_bvh_bytes(triangles):
    """Bytes Warp 1.19 allocates for a mesh BVH over ``triangles`` triangles beside the
    points and indices (``WarpRefitBaseline``)."""
    return (24 + 4) * triangles + 36 * (2 * triangles - 1) if triangles else 0


class EmbreeBaseline:
    """An Embree scene of the evaluated mesh, rebuilt every pose (``embreex``)."""

    name = "embree"
    bytes_source = ("measured: Embree's own memory monitor (rtcSetDeviceMemoryMonitorFunction) "
                    "over the commit of the same scene, its vertex and index buffers left out; "
                    "these are the bytes Embree allocates, in the blocks its allocator takes "
                    "(a round 64 MiB on the 1 M mesh), not the bytes its nodes fill")

    def __init__(self, mesh):
        from embreex.rtcore import EmbreeDevice

        self.vertex_count = len(mesh.vertices)
        self.faces = np.ascontiguousarray(mesh.triangles, np.int32)
        self.rest = np.asarray(mesh.vertices, np.float32)
        self.device = EmbreeDevice()       # once, as an application keeps its device
        self.pool = ThreadPoolExecutor(EMBREE_THREADS, thread_name_prefix="vdnif-embree")
        self.scene = None

    def rebuild(self, obj):
        from embreex.mesh_construction import TriangleMesh
        from embreex.rtcore_scene import EmbreeScene

        evaluate_s = evaluation_s(obj)
        start = time.perf_counter()
        vertices = evaluated_vertices(obj, self.vertex_count)
        read_s = time.perf_counter() - start
        start = time.perf_counter()
        self.scene = None                  # the previous pose's scene is released first
        scene = EmbreeScene(self.device, robust=True)
        TriangleMesh(scene, vertices, self.faces)
        copy_s = time.perf_counter() - start
        start = time.perf_counter()
        nothing = np.empty((0, 3), np.float32)
        scene.run(nothing, nothing)        # the first run commits: Embree builds its BVH
        self.scene = scene
        return {"evaluate_s": evaluate_s, "read_s": read_s, "copy_s": copy_s,
                "commit_s": time.perf_counter() - start}

    def cast(self, origins, directions):
        origins = np.ascontiguousarray(origins, np.float32)
        directions = np.ascontiguousarray(directions, np.float32)
        bounds = np.linspace(0, len(origins), EMBREE_THREADS + 1).astype(int)
        parts = list(self.pool.map(
            lambda s: self.scene.run(origins[s[0]:s[1]], directions[s[0]:s[1]], output=True),
            zip(bounds[:-1], bounds[1:])))
        hit = np.concatenate([part["geomID"] for part in parts]) >= 0
        tfar = np.concatenate([part["tfar"] for part in parts]).astype(np.float64)
        return hit, np.where(hit, tfar, np.inf)

    def bvh_bytes(self):
        return embree_bytes(self.rest, self.faces)["bvh"]

    def close(self):
        self.scene = None
        self.pool.shutdown()


def embree_bytes(vertices, triangles):
    """{"buffers", "bvh"}: bytes Embree allocates for a robust scene of ``triangles`` (T, 3)
    over ``vertices`` (V, 3) as ``embreex`` builds it (its own float3 vertex buffer with a
    16-byte stride, a uint3 index buffer), counted by Embree's memory monitor: the buffers,
    then what the commit (the BVH build) keeps. Calls Embree's C API directly (ctypes on the
    library inside ``embreex``): the binding does not expose the monitor."""
    import embreex

    folder = os.path.join(os.path.dirname(os.path.dirname(embreex.__file__)), "embreex.libs")
    found = glob.glob(os.path.join(folder, "libembree4*")) or glob.glob(
        os.path.join(os.path.dirname(embreex.__file__), "libembree4*"))
    if not found:
        raise VDNIFError(f"cannot find Embree's library beside embreex in '{folder}'")
    lib = _embree_api(found[0])
    allocated = [0]

    @_MONITOR
    def monitor(_, size, __):
        allocated[0] += size
        return True

    vertices = np.asarray(vertices, np.float32).reshape(-1, 3)
    triangles = np.ascontiguousarray(triangles, np.uint32).reshape(-1, 3)
    device = lib.rtcNewDevice(None)
    lib.rtcSetDeviceMemoryMonitorFunction(device, monitor, None)
    scene = lib.rtcNewScene(device)
    try:
        lib.rtcSetSceneFlags(scene, _RTC_SCENE_FLAG_ROBUST)
        geometry = lib.rtcNewGeometry(device, _RTC_GEOMETRY_TYPE_TRIANGLE)
        padded = np.zeros((len(vertices), 4), np.float32)
        padded[:, :3] = vertices
        for kind, format_, stride, data in ((_RTC_BUFFER_TYPE_VERTEX, _RTC_FORMAT_FLOAT3, 16,
                                             padded),
                                            (_RTC_BUFFER_TYPE_INDEX, _RTC_FORMAT_UINT3, 12,
                                             triangles)):
            target = lib.rtcSetNewGeometryBuffer(geometry, kind, 0, format_, stride, len(data))
            ctypes.memmove(target, data.ctypes.data, data.nbytes)
        lib.rtcCommitGeometry(geometry)
        lib.rtcAttachGeometry(scene, geometry)
        lib.rtcReleaseGeometry(geometry)
        buffers = allocated[0]
        lib.rtcCommitScene(scene)
        return {"buffers": int(buffers), "bvh": int(allocated[0] - buffers)}
    finally:
        lib.rtcReleaseScene(scene)
        lib.rtcReleaseDevice(device)


# Embree 4's C API (include/embree4/rtcore_*.h): the few calls and constants embree_bytes uses.
_MONITOR = ctypes.CFUNCTYPE(ctypes.c_bool, ctypes.c_void_p, ctypes.c_ssize_t, ctypes.c_bool)
_RTC_SCENE_FLAG_ROBUST = 1 << 2
_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX, _RTC_BUFFER_TYPE_VERTEX = 0, 1
_RTC_FORMAT_UINT3, _RTC_FORMAT_FLOAT3 = 0x5003, 0x9003


def _embree_api(path):
    lib = ctypes.CDLL(path)
    pointer = ctypes.c_void_p
    for name, result, arguments in (
            ("rtcNewDevice", pointer, [ctypes.c_char_p]),
            ("rtcSetDeviceMemoryMonitorFunction", None, [pointer, _MONITOR, pointer]),
            ("rtcNewScene", pointer, [pointer]),
            ("rtcSetSceneFlags", None, [pointer, ctypes.c_int]),
            ("rtcNewGeometry", pointer, [pointer, ctypes.c_int]),
            ("rtcSetNewGeometryBuffer", pointer, [pointer, ctypes.c_int, ctypes.c_uint,
                                                  ctypes.c_int, ctypes.c_size_t,
                                                  ctypes.c_size_t]),
            ("rtcAttachGeometry", ctypes.c_uint, [pointer, pointer]),
            ("rtcCommitGeometry", None, [pointer]), ("rtcReleaseGeometry", None, [pointer]),
            ("rtcCommitScene", None, [pointer]), ("rtcReleaseScene", None, [pointer]),
            ("rtcReleaseDevice", None, [pointer])):
        function = getattr(lib, name)
        function.restype, function.argtypes = result, arguments
    return lib


def make_baselines(mesh, device="cpu"):
    """Every baseline of ``BASELINES`` for the rest ``mesh`` (the Warp one on ``device``)."""
    return [BVHTreeBaseline(mesh), WarpRefitBaseline(mesh, device), EmbreeBaseline(mesh)]
