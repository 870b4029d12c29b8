"""Embree through its C API (studies/baselines_embree.py) against brute force: the same rays
hit, at the same distances within float32 rounding, on a refit scene and on a rebuilt one,
before and after the shared vertices move, from outside and from inside a closed mesh, at one
thread and at two; the packets' layout stays inside its rows; the BVH bytes are Embree's own
count; the packets hit what embreex's own loop hits."""

import numpy as np
import pytest
from oracles.geometry import BruteForceCaster

from vdnif_addon.errors import VDNIFError
from vdnif_addon.studies import baselines_embree as embree

DISTANCE_TOLERANCE = 1e-5      # float32 distances of rays a few units long


def soup(rng, count=200):
    """A random triangle soup: vertices (3 count, 3), triangles (count, 3)."""
    return rng.random((3 * count, 3)), np.arange(3 * count).reshape(-1, 3)


def sphere(rows=12, columns=24):
    """A closed UV sphere of radius 1: vertices, triangles."""
    theta = np.linspace(0, np.pi, rows + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, columns, endpoint=False)
    ring = np.stack([np.sin(theta)[:, None] * np.cos(phi), np.sin(theta)[:, None] * np.sin(phi),
                     np.cos(theta)[:, None] * np.ones_like(phi)], -1).reshape(-1, 3)
    vertices = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    triangles = []
    for c in range(columns):
        n = (c + 1) % columns
        triangles.append([0, 1 + c, 1 + n])
        for r in range(rows - 2):
            a, b = 1 + r * columns, 1 + (r + 1) * columns
            triangles += [[a + c, b + c, b + n], [a + c, b + n, a + n]]
        last = 1 + (rows - 2) * columns
        triangles.append([last + c, len(vertices) - 1, last + n])
    return vertices, np.array(triangles)


def rays(rng, count, low=-1.0, high=2.0):
    """Rays from random points of [low, high]^3 towards random points of [-0.3, 1.3]^3 (the
    soup fills the unit cube): most cross it, some pass beside it."""
    origins = rng.uniform(low, high, (count, 3))
    directions = rng.uniform(-0.3, 1.3, (count, 3)) - origins
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def brute_force(vertices, triangles, origins, directions, max_distance=np.inf):
    """(index, t) of the float32 inputs Embree sees, cast in float64."""
    as_float32 = [np.asarray(x, np.float32).astype(np.float64)
                  for x in (vertices, origins, directions)]
    return BruteForceCaster(as_float32[0][triangles]).cast(
        as_float32[1], as_float32[2], np.broadcast_to(max_distance, (len(origins),)))


def assert_same_hits(cast, expected):
    """The same triangle hit (or missed) by every ray, at the same distance."""
    (index, t), (expected_index, expected_t) = cast, expected
    np.testing.assert_array_equal(index, expected_index)
    hit = index >= 0
    np.testing.assert_allclose(t[hit], expected_t[hit], rtol=0, atol=DISTANCE_TOLERANCE)
    assert np.isinf(t[~hit]).all()


@pytest.fixture(params=[1, 2], ids=["1 thread", "2 threads"])
def device(request):
    made = embree.EmbreeDevice(request.param)
    yield made
    made.close()


@pytest.mark.parametrize("refit", [True, False], ids=["refit", "rebuild"])
def test_first_hits_equal_brute_force_before_and_after_the_vertices_move(device, refit):
    rng = np.random.default_rng(1)
    vertices, triangles = soup(rng)
    scene = embree.EmbreeScene(device, vertices, triangles, refit)
    try:
        for pose in range(3):        # the rest, then two moves: small, then large
            if pose:
                vertices = vertices + rng.normal(scale=0.02 if pose == 1 else 0.3,
                                                 size=vertices.shape)
                scene.vertices[:] = vertices
                scene.commit()
            origins, directions = rays(rng, 3001)    # not a whole number of packets
            expected = brute_force(vertices, triangles, origins, directions)
            assert 300 < (expected[0] >= 0).sum() < 2900    # some hit, some miss
            assert_same_hits(scene.cast(origins, directions), expected)
    finally:
        scene.close()


@pytest.mark.parametrize("refit", [True, False], ids=["refit", "rebuild"])
def test_rays_from_inside_a_closed_mesh_hit_its_inner_side(device, refit):
    rng = np.random.default_rng(2)
    vertices, triangles = sphere()
    scene = embree.EmbreeScene(device, vertices, triangles, refit)
    try:
        for scale in (1.0, 1.5):                 # the sphere, then grown by a refit
            if scale != 1.0:
                vertices = vertices * scale
                scene.vertices[:] = vertices
                scene.commit()
            origins, directions = rays(rng, 500, -0.5, 0.5)
            index, t = scene.cast(origins, directions)
            assert (index >= 0).all()
            assert_same_hits((index, t), brute_force(vertices, triangles, origins, directions))
            # outward rays from the centre: the faceted sphere's inner side, just inside
            index, t = scene.cast(np.zeros_like(origins), directions)
            assert (index >= 0).all() and (t <= scale + 1e-6).all() and (t > 0.95 * scale).all()
    finally:
        scene.close()


def test_a_reach_stops_rays_as_brute_force_does(device):
    """Per-ray reaches (as secondary rays have): a hit beyond its ray's reach is a miss; a
    smaller cast after a larger one (the packets of the larger kept) sets every lane again."""
    rng = np.random.default_rng(6)
    vertices, triangles = soup(rng)
    scene = embree.EmbreeScene(device, vertices, triangles, refit=True)
    try:
        origins, directions = rays(rng, 3001)
        scene.cast(origins, directions)
        for count in (1000, 37):
            origins, directions = rays(rng, count)
            reach = rng.uniform(0.0, 3.0, count)
            expected = brute_force(vertices, triangles, origins, directions, reach)
            unbounded = brute_force(vertices, triangles, origins, directions)
            assert ((expected[0] < 0) & (unbounded[0] >= 0)).sum() > count // 20
            assert_same_hits(scene.cast(origins, directions, reach), expected)
            assert_same_hits(scene.cast(origins, directions, 0.5),
                             brute_force(vertices, triangles, origins, directions, 0.5))
    finally:
        scene.close()


def test_few_rays_and_none(device):
    vertices, triangles = sphere()
    scene = embree.EmbreeScene(device, vertices, triangles, refit=True)
    try:
        index, t = scene.cast(np.zeros((5, 3)), np.tile([[1.0, 0, 0]], (5, 1)))
        assert (index >= 0).all() and np.allclose(t, 1.0, atol=0.02)
        index, t = scene.cast(np.full((3, 3), 5.0), np.tile([[1.0, 0, 0]], (3, 1)))
        assert (index == -1).all() and np.isinf(t).all()      # pointing away: all miss
        index, t = scene.cast(np.empty((0, 3)), np.empty((0, 3)))
        assert index.shape == t.shape == (0,)
    finally:
        scene.close()


def test_a_cast_writes_only_inside_its_packet():
    """A packet's rows (ROWS) hold everything Embree writes: the packet after it, filled
    with a sentinel, is untouched by a cast of hits (instance rows written too)."""
    device = embree.EmbreeDevice(1)
    vertices, triangles = sphere()
    scene = embree.EmbreeScene(device, vertices, triangles, refit=False)
    try:
        width = device.width
        block = embree.aligned_empty((2, len(embree.ROWS), width), np.float32)
        block.view(np.uint32)[:] = 0xA5A5A5A5
        block[0] = 0
        block[0, embree.ROW["dir_x"]] = 1.0
        block[0, embree.ROW["tfar"]] = np.inf
        block[0].view(np.uint32)[embree.ROW["mask"]] = embree.EVERY_MASK_BIT
        block[0].view(np.uint32)[embree.ROW["geomID"]] = embree.RTC_INVALID_GEOMETRY_ID
        valid = embree.aligned_empty((1, width), np.int32)
        valid[:] = -1
        assert block.ctypes.data % embree.ALIGNMENT == 0 == valid.ctypes.data % 64
        scene._cast_packets([valid.ctypes.data], [block.ctypes.data])
        assert (block[0].view(np.uint32)[embree.ROW["geomID"]] == 0).all()
        assert np.allclose(block[0, embree.ROW["tfar"]], 1.0, atol=0.02)
        assert (block[0].view(np.uint32)[embree.ROW["instID"]]
                == embree.RTC_INVALID_GEOMETRY_ID).all()
        assert (block[1].view(np.uint32) == 0xA5A5A5A5).all()
    finally:
        scene.close()
        device.close()


def test_bvh_bytes_come_from_embrees_own_memory_monitor():
    device = embree.EmbreeDevice(1)
    rng = np.random.default_rng(3)
    try:
        for refit in (True, False):
            per_triangle = []
            for count in (2000, 8000):
                scene = embree.EmbreeScene(device, *soup(rng, count), refit)
                per_triangle.append(scene.bvh_bytes() / count)
                scene.close()
            # a BVH's bytes grow with its triangles: tens of bytes per triangle each time
            assert all(10 < size < 500 for size in per_triangle)
            assert 0.5 < per_triangle[1] / per_triangle[0] < 2
    finally:
        device.close()


def test_packets_hit_what_embreexs_own_loop_hits():
    """The same rays through embreex's ``run`` (a C loop of rtcIntersect1 on a scene it
    builds): the same hits and distances."""
    from embreex.mesh_construction import TriangleMesh
    from embreex.rtcore import EmbreeDevice
    from embreex.rtcore_scene import EmbreeScene

    rng = np.random.default_rng(4)
    vertices, triangles = soup(rng)
    origins, directions = rays(rng, 2000)
    other = EmbreeScene(EmbreeDevice(), robust=True)
    TriangleMesh(other, vertices.astype(np.float32), triangles.astype(np.int32))
    ran = other.run(origins.astype(np.float32), directions.astype(np.float32), output=True)
    expected_hit = ran["geomID"] >= 0
    device = embree.EmbreeDevice(2)
    scene = embree.EmbreeScene(device, vertices, triangles, refit=False)
    try:
        index, t = scene.cast(origins, directions)
        hit = index >= 0
        np.testing.assert_array_equal(hit, expected_hit)
        np.testing.assert_array_equal(index[hit], ran["primID"][hit])
        np.testing.assert_array_equal(t[hit], ran["tfar"][hit])
    finally:
        scene.close()
        device.close()


_ONE_THREAD_BUILD = """
import sys, time
import numpy as np
sys.path[:0] = [{repo!r}, {tests!r}, {here!r}]
from test_baselines_embree import soup
from vdnif_addon.studies import baselines_embree as embree
device = embree.EmbreeDevice(1)
vertices, triangles = soup(np.random.default_rng(5), 60_000)
scene = embree.EmbreeScene(device, vertices, triangles, refit=False)
process, caller = time.process_time(), time.thread_time()
for _ in range(3):
    scene.commit()
print(time.process_time() - process, time.thread_time() - caller)
scene.close()
device.close()
"""


def test_a_one_thread_device_builds_on_the_calling_thread_alone():
    """The 1-thread setting is one thread: the process spends no CPU time beside the caller's
    while Embree builds (its task scheduler's workers would). In a process of its own: the
    workers of other tests' devices, idling in this one, would be counted too."""
    import pathlib
    import subprocess
    import sys

    here = pathlib.Path(__file__).resolve().parent
    code = _ONE_THREAD_BUILD.format(repo=str(here.parents[1]), tests=str(here.parent),
                                    here=str(here))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=True)
    process, caller = map(float, done.stdout.split()[-2:])
    assert caller > 0.02 and process - caller < 0.1 * caller


def test_bad_settings_are_one_line():
    with pytest.raises(VDNIFError, match="thread count 0 must be at least 1"):
        embree.EmbreeDevice(0)
    with pytest.raises(VDNIFError, match="4, 8 or 16 rays wide, not 5"):
        embree.EmbreeDevice(1, width=5)
