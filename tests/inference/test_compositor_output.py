"""Compositor-ready output: the passes written for one frame open in Blender as one multilayer
EXR with Cycles' pass names and the values written, and the PNG previews are transparent
where the rays miss."""

import math

import numpy as np
import pytest
from blender_exr import read_multilayer

HEIGHT, WIDTH = 19, 5      # more rows than one 16-row block of the EXR's compression


def random_passes(core, rng):
    """Passes of HEIGHT x WIDTH rays with random hits and values (materials as used-slot
    indices 0..2)."""
    rays = HEIGHT * WIDTH
    normal = rng.normal(size=(rays, 3))
    return core("passes").Passes(
        hit=rng.random(rays) < 0.6, distance=rng.uniform(1, 9, rays),
        normal=normal / np.linalg.norm(normal, axis=1, keepdims=True),
        albedo=rng.random((rays, 3)).astype(np.float32),
        material=rng.integers(0, 3, rays).astype(np.int32))


def test_one_multilayer_exr_per_frame_reads_back_in_blender(empty_scene, core, tmp_path):
    import bpy

    rng = np.random.default_rng(4)
    passes = random_passes(core, rng)
    scale = rng.uniform(0.5, 2.0, HEIGHT * WIDTH)        # local / world length per ray
    slots = np.array([2, 5, 7])
    angle = math.radians(30)
    world = np.diag([2.0, 2.0, 0.5, 1.0])                # scaled and turned about z
    world[:2, :2] = 2.0 * np.array([[math.cos(angle), -math.sin(angle)],
                                    [math.sin(angle), math.cos(angle)]])
    written = core("blender.steps").write_passes(tmp_path, passes, HEIGHT, WIDTH, scale,
                                                slots=slots, frame=30, world_matrix=world)
    names = sorted(path.name for path in written)
    assert names == sorted([f"{name}.0030.png" for name in
                            ("hit", "normal", "albedo", "distance", "material")]
                           + ["passes.0030.exr"])

    layer, read = read_multilayer(tmp_path / "passes.0030.exr", WIDTH, HEIGHT)
    assert layer == "ViewLayer"
    assert set(read) == {"Combined", "Depth", "Normal", "DiffCol", "IndexMA"}
    hit = passes.hit.reshape(HEIGHT, WIDTH)
    # Expected values from the definitions: world distance = local / scale; a normal maps
    # by the inverse transpose of the world matrix's 3x3 part; the material is the slot.
    depth = np.where(passes.hit, passes.distance / scale, 1e10).reshape(HEIGHT, WIDTH)
    normal = passes.normal @ np.linalg.inv(world[:3, :3])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(passes.hit[:, None], normal, 0).reshape(HEIGHT, WIDTH, 3)
    albedo = np.where(passes.hit[:, None], passes.albedo, 0).reshape(HEIGHT, WIDTH, 3)
    slot = np.where(passes.hit, slots[passes.material], 0).reshape(HEIGHT, WIDTH)
    np.testing.assert_allclose(read["Depth"][..., 0], depth, rtol=1e-6)
    np.testing.assert_allclose(read["Normal"][..., :3], normal, atol=1e-6)
    np.testing.assert_allclose(read["DiffCol"][..., :3], albedo, atol=1e-6)
    np.testing.assert_array_equal(read["IndexMA"][..., 0], slot)
    np.testing.assert_array_equal(read["Combined"][..., 3], hit)
    np.testing.assert_allclose(read["Combined"][..., :3], albedo, atol=1e-6)

    for name in ("albedo", "hit"):
        png = bpy.data.images.load(str(tmp_path / f"{name}.0030.png"))
        pixels = np.empty(HEIGHT * WIDTH * 4, np.float32)
        png.pixels.foreach_get(pixels)
        np.testing.assert_array_equal(pixels.reshape(HEIGHT, WIDTH, 4)[::-1, :, 3], hit)


def test_exr_layout_is_the_formats(core):
    """The parts of the file a reader relies on, from the format's specification: the magic
    number, version 2, channels sorted by name, an offset table whose entries point at chunks
    that start with their first row."""
    import struct

    exr = core("inference.exr")
    image = np.arange(2 * 3 * 40, dtype=np.float32).reshape(40, 3, 2)
    data = exr.multilayer_bytes({"B": image[..., :1], "A": image[..., 1:]},
                                {"B": "Z", "A": "X"}, "L")
    assert struct.unpack("<ii", data[:8]) == (20000630, 2)
    assert data.index(b"L.A.X\0") < data.index(b"L.B.Z\0")
    # the header ends after screenWindowWidth's 4-byte value and the terminating zero byte
    header_end = data.index(b"screenWindowWidth") + len(b"screenWindowWidth\0float\0") + 8 + 1
    offsets = np.frombuffer(data[header_end:header_end + 8 * 3], "<u8")
    assert [struct.unpack("<i", data[int(o):int(o) + 4])[0] for o in offsets] == [0, 16, 32]
    with pytest.raises(ValueError, match="pass B is"):
        exr.multilayer_bytes({"B": image}, {"B": "Z"}, "L")
