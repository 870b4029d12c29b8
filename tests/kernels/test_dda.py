"""The static DDA walk against the deformed-space walk on undeformed cells (no bpy): both must
give the same cells per ray in the same order with the same distances and rest points; and
the DDA kernel against the numpy DDA it replaced."""

import numpy as np
import pytest
from oracles import dda as oracle

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import voxels
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.tracing import static_grid as dda
from vdnif_addon.tracing import traverse


@pytest.fixture(scope="module")
def blob():
    """A random triangle soup around the unit sphere, voxelized at R=10: occupied cells with
    holes and concavities, so rays leave and re-enter the occupied set."""
    rng = np.random.default_rng(11)
    vertices = rng.normal(size=(80, 3))
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    return voxels.build_grid(vertices, rng.integers(0, 80, size=(160, 3)), 10)


def deformed_walk(grid, origins, directions, **kw):
    return traverse.traverse(DeviceCells(grid), origins, directions, **kw)


def assert_same_segments(grid, origins, directions, **kw):
    expected = deformed_walk(grid, origins, directions, **kw)
    got = dda.StaticGrid(grid).traverse(origins, directions, **kw)
    assert expected.truncated == 0 and len(expected) > 0
    assert_same_as_numpy_dda(grid, got, origins, directions, **kw)
    assert len(got) == len(expected)
    np.testing.assert_array_equal(got.ray, expected.ray)
    np.testing.assert_array_equal(got.cell, expected.cell)
    for name in ("t0", "t1"):
        np.testing.assert_allclose(getattr(got, name), getattr(expected, name), rtol=1e-9,
                                   atol=1e-12)
    for name in ("p0", "p1"):
        np.testing.assert_allclose(getattr(got, name), getattr(expected, name), rtol=0,
                                   atol=1e-9 * grid.extent)
    return got


def assert_same_as_numpy_dda(grid, got, origins, directions, **kw):
    """The kernel gives the numpy DDA's segments, bit for bit (same formulas, same order)."""
    expected = oracle.StaticGrid(grid).traverse(origins, directions, **kw)
    assert len(got) == len(expected)
    for name in ("ray", "cell", "t0", "t1", "p0", "p1"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))


def test_rays_from_outside(blob):
    rng = np.random.default_rng(1)
    origins = rng.normal(size=(200, 3))
    origins *= 3.0 / np.linalg.norm(origins, axis=1, keepdims=True)
    directions = rng.normal(size=(200, 3)) * 0.3 - origins
    segments = assert_same_segments(blob, origins, directions)
    assert len(np.unique(segments.ray)) > 150               # most rays cross the blob


def test_rays_starting_inside_the_grid(blob):
    """Origins anywhere in the grid, in occupied and empty cells alike: pieces start at 0."""
    rng = np.random.default_rng(2)
    origins = blob.origin + rng.random((200, 3)) * blob.dims * blob.voxel_size
    directions = rng.normal(size=(200, 3))
    segments = assert_same_segments(blob, origins, directions)
    assert (segments.t0 == 0).sum() > 20                    # some start in an occupied cell


def test_axis_parallel_rays(blob):
    """Rays along +-x, +-y, +-z off the lattice planes: two slabs never end."""
    rng = np.random.default_rng(3)
    axes = np.repeat(np.concatenate([np.eye(3), -np.eye(3)]), 30, axis=0)
    origins = rng.uniform(-0.9, 0.9, size=(len(axes), 3)) - 2.5 * axes
    segments = assert_same_segments(blob, origins, axes)
    assert set(np.unique(segments.ray) // 30) == set(range(6))   # every direction crosses


def test_max_distance_and_degenerate_rays(blob):
    """A limit ends a ray like the deformed walk does; a zero direction walks nowhere."""
    rng = np.random.default_rng(4)
    origins = np.tile([[-3.0, 0.1, 0.05]], (40, 1))
    directions = np.tile([[1.0, 0.02, 0.01]], (40, 1)) + rng.normal(size=(40, 3)) * 0.05
    assert_same_segments(blob, origins, directions, max_distance=rng.uniform(2, 4, 40))
    none = dda.StaticGrid(blob).traverse(origins[:3], np.zeros((3, 3)))
    assert len(none) == 0


def test_a_full_segment_buffer_resumes_where_it_stopped(blob):
    """A buffer of 7 segments: every launch stops when it is full and the next goes on, to
    the same segments as one launch (which equal the numpy DDA's, above)."""
    from vdnif_addon.kernels.dda import dda_segments

    rng = np.random.default_rng(5)
    origins = rng.normal(size=(50, 3))
    origins *= 3.0 / np.linalg.norm(origins, axis=1, keepdims=True)
    directions = rng.normal(size=(50, 3)) * 0.3 - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    grid = dda.StaticGrid(blob)
    far = np.full(50, np.inf)
    small = dda_segments(grid, origins, directions, far, "cpu", capacity=7)
    whole = dda_segments(grid, origins, directions, far, "cpu")
    assert len(small) > 100
    for name in ("ray", "cell", "t0", "t1", "p0", "p1"):
        np.testing.assert_array_equal(getattr(small, name), getattr(whole, name))


def test_bad_input_is_one_line(blob):
    with pytest.raises(VDNIFError, match="shape"):
        dda.StaticGrid(blob).traverse(np.zeros((3, 3)), np.zeros((2, 3)))
