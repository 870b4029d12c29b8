"""Embree 4 through its C API: ctypes on the library that ``embreex`` ships, with none of the
binding's per-element copies.

``EmbreeScene`` holds one triangle mesh whose vertices live in a numpy array Embree shares
(``rtcSetSharedGeometryBuffer``: float3 with a 16-byte stride, one padding row for Embree's
16-byte loads), so a pose writes its vertices there and commits: with ``refit`` the scene is
dynamic, of build quality LOW (Embree's two-level BVH) and the geometry's build quality
``RTC_BUILD_QUALITY_REFIT`` (Embree keeps the tree and updates its bounds, as Cycles does for
a deforming mesh in the viewport); without it the scene is static and every commit builds a
new BVH. Both are robust (watertight) scenes.

Casts go through ``rtcIntersect16`` (the widest call: the fewest ctypes calls; native packets
on AVX-512, elsewhere Embree loops over the packet's rays) over numpy-packed
structure-of-arrays packets, split over ``threads`` Python threads (ctypes releases the GIL
for each call). ``embreex``'s ``run`` (a C loop of ``rtcIntersect1``) casts the same rays
faster where 16-wide packets are not native (about 1.5x on the bunny's 256x256 views on a
2-core AVX2 EPYC), but only on a scene that embreex itself builds with its per-element copy,
so it can neither refit nor share the vertex array: the Embree rows cast with packets.
``threads`` is also the device's build threads (``threads=N``): Embree's task scheduler takes
the largest count of the devices alive, so only one device of this module should live at a
time.
"""

import collections
import ctypes
import glob
import itertools
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import VDNIFError

# Embree 4.4's C API (include/embree4/rtcore_*.h).
RTC_SCENE_FLAG_DYNAMIC, RTC_SCENE_FLAG_ROBUST = 1 << 0, 1 << 2
RTC_BUILD_QUALITY_LOW, RTC_BUILD_QUALITY_MEDIUM, RTC_BUILD_QUALITY_REFIT = 0, 1, 3
RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_BUFFER_TYPE_INDEX, RTC_BUFFER_TYPE_VERTEX = 0, 1
RTC_FORMAT_UINT3, RTC_FORMAT_FLOAT3 = 0x5003, 0x9003
RTC_INVALID_GEOMETRY_ID = 0xFFFFFFFF
EVERY_MASK_BIT = 0xFFFFFFFF          # a ray's mask: it sees every geometry
RTC_RAY_QUERY_FLAG_COHERENT = 1 << 16
RTC_FEATURE_FLAG_ALL = 0xFFFFFFFF
# rtcGetDeviceProperty: whether 4-, 8- and 16-wide packets run natively.
NATIVE_PACKET_PROPERTY = {16: 34, 8: 33, 4: 32}
PACKET_WIDTH = 16       # the widest call: fewest ctypes calls, native packets on AVX-512
RTC_DEVICE_PROPERTY_VERSION = 0

# RTCRayHitN, rows of N lanes: the ray (org, tnear, dir, time, tfar, mask, id, flags), then
# the hit (Ng, u, v, primID, geomID, instID[1], instPrimID[1]); RTC_MAX_INSTANCE_LEVEL_COUNT
# is 1 in this build, as embreex's own declarations say (tests check that a cast writes
# nothing past these rows).
ROWS = ("org_x", "org_y", "org_z", "tnear", "dir_x", "dir_y", "dir_z", "time", "tfar",
        "mask", "id", "flags", "Ng_x", "Ng_y", "Ng_z", "u", "v", "primID", "geomID", "instID",
        "instPrimID")
ROW = {name: index for index, name in enumerate(ROWS)}
ALIGNMENT = 64                      # RTCRayHit16's; 8- and 4-wide need 32 and 16


class RTCIntersectArguments(ctypes.Structure):
    _fields_ = [("flags", ctypes.c_uint32), ("feature_mask", ctypes.c_uint32),
                ("context", ctypes.c_void_p), ("filter", ctypes.c_void_p),
                ("intersect", ctypes.c_void_p),
                ("spare", ctypes.c_float * 8)]   # room for optional fields, left zero


MONITOR = ctypes.CFUNCTYPE(ctypes.c_bool, ctypes.c_void_p, ctypes.c_ssize_t, ctypes.c_bool)


def library_path():
    """Path of the Embree 4 library inside the installed ``embreex`` wheel."""
    import embreex

    package = os.path.dirname(embreex.__file__)
    found = (glob.glob(os.path.join(os.path.dirname(package), "embreex.libs", "libembree4*"))
             or glob.glob(os.path.join(package, "libembree4*")))
    if not found:
        raise VDNIFError(f"cannot find Embree's library beside embreex in '{package}'")
    return found[0]


_API = {}


def api():
    """Embree's C functions (ctypes), loaded once."""
    if "lib" not in _API:
        lib = ctypes.CDLL(library_path())
        p, u, s = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
        for name, result, arguments in (
                ("rtcNewDevice", p, [ctypes.c_char_p]), ("rtcReleaseDevice", None, [p]),
                ("rtcGetDeviceError", ctypes.c_int, [p]),
                ("rtcGetDeviceLastErrorMessage", ctypes.c_char_p, [p]),
                ("rtcGetDeviceProperty", ctypes.c_ssize_t, [p, ctypes.c_int]),
                ("rtcSetDeviceMemoryMonitorFunction", None, [p, MONITOR, p]),
                ("rtcNewScene", p, [p]), ("rtcSetSceneFlags", None, [p, ctypes.c_int]),
                ("rtcSetSceneBuildQuality", None, [p, ctypes.c_int]),
                ("rtcCommitScene", None, [p]), ("rtcReleaseScene", None, [p]),
                ("rtcNewGeometry", p, [p, ctypes.c_int]),
                ("rtcSetSharedGeometryBuffer", None, [p, ctypes.c_int, u, ctypes.c_int, p,
                                                      s, s, s]),
                ("rtcSetGeometryBuildQuality", None, [p, ctypes.c_int]),
                ("rtcUpdateGeometryBuffer", None, [p, ctypes.c_int, u]),
                ("rtcCommitGeometry", None, [p]), ("rtcAttachGeometry", u, [p, p]),
                ("rtcReleaseGeometry", None, [p]),
                *((f"rtcIntersect{width}", None, [p, p, p, p]) for width in (4, 8, 16))):
            function = getattr(lib, name)
            function.restype, function.argtypes = result, arguments
        _API["lib"] = lib
    return _API["lib"]


def aligned_empty(shape, dtype):
    """An uninitialized numpy array whose data starts on an ``ALIGNMENT``-byte boundary."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(size + ALIGNMENT, np.uint8)
    start = -raw.ctypes.data % ALIGNMENT
    return raw[start:start + size].view(dtype).reshape(shape)


class EmbreeDevice:
    """An Embree device whose builds, and the casts of its scenes, run on ``threads``
    threads, in packets of ``width`` rays (``native``: whether this CPU traverses that
    width as a packet; Embree loops over the rays of a wider one)."""

    def __init__(self, threads, width=PACKET_WIDTH):
        if threads < 1:
            raise VDNIFError(f"Embree thread count {threads} must be at least 1")
        self.lib = api()
        self.threads = threads
        self.handle = self.lib.rtcNewDevice(f"threads={threads}".encode())
        if not self.handle:
            raise VDNIFError(f"Embree refused a device with {threads} thread(s)")
        if width not in NATIVE_PACKET_PROPERTY:
            raise VDNIFError(f"Embree packets are 4, 8 or 16 rays wide, not {width}")
        self.width = width
        self.native = bool(self.lib.rtcGetDeviceProperty(self.handle,
                                                         NATIVE_PACKET_PROPERTY[width]))
        self.version = int(self.lib.rtcGetDeviceProperty(self.handle,
                                                         RTC_DEVICE_PROPERTY_VERSION))

    def check(self, what):
        """Raises a VDNIFError naming ``what`` if Embree reported an error since the last
        check."""
        code = self.lib.rtcGetDeviceError(self.handle)
        if code:
            message = (self.lib.rtcGetDeviceLastErrorMessage(self.handle) or b"").decode()
            raise VDNIFError(f"Embree failed to {what}: error {code} {message}".strip())

    def close(self):
        if self.handle:
            self.lib.rtcReleaseDevice(self.handle)
            self.handle = None


class EmbreeScene:
    """One triangle mesh, ``vertices`` (V, 3) and ``triangles`` (T, 3), in an Embree scene
    of ``device`` that shares its vertex and index arrays; ``refit`` picks how a commit
    updates the BVH (see the module). Built on creation."""

    def __init__(self, device, vertices, triangles, refit):
        self.device, self.refit = device, refit
        lib = device.lib
        self.lib = lib
        vertices = np.asarray(vertices, np.float32).reshape(-1, 3)
        self.count = len(vertices)
        self.buffer = aligned_empty((self.count + 1, 4), np.float32)
        self.buffer[:] = 0
        self.vertices = self.buffer[:self.count, :3]   # a pose writes its vertices here
        self.vertices[:] = vertices
        self.indices = np.ascontiguousarray(triangles, np.uint32).reshape(-1, 3)
        self.scene = lib.rtcNewScene(device.handle)
        lib.rtcSetSceneFlags(self.scene, RTC_SCENE_FLAG_ROBUST
                             | (RTC_SCENE_FLAG_DYNAMIC if refit else 0))
        # Embree picks its two-level BVH, whose meshes a commit may refit, for a scene of
        # build quality LOW; any other scene quality rebuilds everything on each commit.
        lib.rtcSetSceneBuildQuality(self.scene, RTC_BUILD_QUALITY_LOW if refit
                                    else RTC_BUILD_QUALITY_MEDIUM)
        self.geometry = lib.rtcNewGeometry(device.handle, RTC_GEOMETRY_TYPE_TRIANGLE)
        lib.rtcSetSharedGeometryBuffer(self.geometry, RTC_BUFFER_TYPE_VERTEX, 0,
                                       RTC_FORMAT_FLOAT3, self.buffer.ctypes.data, 0, 16,
                                       self.count)
        lib.rtcSetSharedGeometryBuffer(self.geometry, RTC_BUFFER_TYPE_INDEX, 0,
                                       RTC_FORMAT_UINT3, self.indices.ctypes.data, 0, 12,
                                       len(self.indices))
        lib.rtcSetGeometryBuildQuality(self.geometry, RTC_BUILD_QUALITY_REFIT if refit
                                       else RTC_BUILD_QUALITY_MEDIUM)
        lib.rtcCommitGeometry(self.geometry)
        lib.rtcAttachGeometry(self.scene, self.geometry)
        lib.rtcCommitScene(self.scene)
        device.check("build the scene")
        self.intersect = getattr(lib, f"rtcIntersect{device.width}")
        self.arguments = RTCIntersectArguments(flags=RTC_RAY_QUERY_FLAG_COHERENT,
                                               feature_mask=RTC_FEATURE_FLAG_ALL)
        self.masks = aligned_empty((2, device.width), np.int32)  # every lane; the last packet's
        self.masks[:] = -1
        self._block = None
        self.pool = (ThreadPoolExecutor(device.threads, thread_name_prefix="vdnif-embree")
                     if device.threads > 1 else None)

    def commit(self):
        """Tells Embree that ``vertices`` moved and updates the BVH (refit or new build)."""
        self.lib.rtcUpdateGeometryBuffer(self.geometry, RTC_BUFFER_TYPE_VERTEX, 0)
        self.lib.rtcCommitGeometry(self.geometry)
        self.lib.rtcCommitScene(self.scene)
        self.device.check("commit the scene")

    def cast(self, origins, directions, max_distance=np.inf):
        """(index (N,) int64 of the hit triangle, -1 on a miss; t (N,) float64, inf on a
        miss): first hits with 0 <= t <= ``max_distance`` (a number or (N,)), the
        interface of ``kernels.cast.MeshCaster``."""
        count = len(origins)
        block = self._packets(count)
        width, packets = block.shape[2], len(block)
        full, rest = divmod(count, width)
        for rows, values in (((ROW["org_x"], ROW["org_y"], ROW["org_z"]), origins),
                             ((ROW["dir_x"], ROW["dir_y"], ROW["dir_z"]), directions)):
            values = np.asarray(values)
            for axis, row in enumerate(rows):
                block[:full, row] = values[:full * width, axis].reshape(full, width)
                block[full:, row] = 0                 # the last packet's spare lanes
                block[full:, row, :rest] = values[full * width:, axis]
        limits = np.broadcast_to(np.asarray(max_distance, np.float32), (count,))
        block[:full, ROW["tfar"]] = limits[:full * width].reshape(full, width)
        block[full:, ROW["tfar"]] = np.inf
        block[full:, ROW["tfar"], :rest] = limits[full * width:]
        block[:, ROW["geomID"]].view(np.uint32)[:] = RTC_INVALID_GEOMETRY_ID
        rays = (block.ctypes.data + block.strides[0] * np.arange(packets)).tolist()
        masks = [self.masks.ctypes.data] * packets
        if count % width:          # the last packet's spare lanes are not cast
            masks[-1] += self.masks.strides[0]
            self.masks[1] = np.arange(width) < count % width
            self.masks[1] *= -1
        parts = np.linspace(0, packets, self.device.threads + 1).astype(int)
        ranges = [(masks[a:b], rays[a:b]) for a, b in zip(parts[:-1], parts[1:])]
        if self.pool is None:
            for part in ranges:
                self._cast_packets(*part)
        else:
            list(self.pool.map(lambda part: self._cast_packets(*part), ranges))
        self.device.check("cast rays")
        hit = block[:, ROW["geomID"]].view(np.uint32).reshape(-1)[:count] \
            != RTC_INVALID_GEOMETRY_ID
        t = block[:, ROW["tfar"]].reshape(-1)[:count].astype(np.float64)
        index = block[:, ROW["primID"]].view(np.uint32).reshape(-1)[:count].astype(np.int64)
        return np.where(hit, index, -1), np.where(hit, t, np.inf)

    def _packets(self, count):
        """The RTCRayHitN packets of ``count`` rays: the first packets of a block kept for
        the largest cast so far (secondary rays come in several counts per pose), whose rows
        a cast does not set keep their values (tnear, time, id, flags 0, every mask bit)."""
        width = self.device.width
        packets = -(-count // width)
        if self._block is None or len(self._block) < packets:
            self._block = aligned_empty((packets, len(ROWS), width), np.float32)
            self._block[:] = 0
            self._block[:, ROW["mask"]].view(np.uint32)[:] = EVERY_MASK_BIT
        return self._block[:packets]

    def _cast_packets(self, masks, rays):
        collections.deque(map(self.intersect, masks, itertools.repeat(self.scene), rays,
                              itertools.repeat(ctypes.addressof(self.arguments))), maxlen=0)

    def bvh_bytes(self):
        """Bytes Embree allocates to build this scene's BVH (its buffers are shared, so
        Embree allocates none for them), counted by Embree's memory monitor over the build
        of a twin scene with the same settings on the same device."""
        allocated = [0]

        @MONITOR
        def monitor(_, size, __):
            allocated[0] += size
            return True

        lib, handle = self.lib, self.device.handle
        lib.rtcSetDeviceMemoryMonitorFunction(handle, monitor, None)
        try:
            twin = EmbreeScene(self.device, self.vertices, self.indices, self.refit)
            counted = allocated[0]          # before the twin frees what it holds
            twin.close()
        finally:
            lib.rtcSetDeviceMemoryMonitorFunction(handle, MONITOR(), None)
        return int(counted)

    def close(self):
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None
        if getattr(self, "scene", None):
            self.lib.rtcReleaseGeometry(self.geometry)
            self.lib.rtcReleaseScene(self.scene)
            self.scene = None
