"""The network's walk past the surface a secondary ray leaves stops at SECONDARY_SELF_REACH:
a surface that faces the same way as the left one but lies farther off is an occluder, not
the left surface met from below (no bpy)."""

import numpy as np
import pytest
from test_secondary import BOX, HEIGHT, box_on_plane, occluders

from vdnif_addon.geometry import voxels
from vdnif_addon.inference import secondary
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.settings import SECONDARY_SELF_REACH


@pytest.fixture(scope="module")
def scene():
    mesh = box_on_plane()
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 16)
    return mesh, grid, DeviceCells(grid, corners=grid.corner_positions())


def inside_the_box(offset):
    """Rays straight up from the plane inside the open-bottomed box, an offset above it,
    leaving the plane's normal (+z): the box's lid, whose normal is +z too, is HEIGHT away."""
    xy = np.linspace(-0.8 * BOX, 0.8 * BOX, 12)
    origins = np.stack([xy, xy[::-1], np.full(12, offset)], 1)
    up = np.tile([0.0, 0.0, 1.0], (12, 1))
    return origins, up, np.full(12, 3.0 * HEIGHT), up


@pytest.mark.parametrize("path", ["brute", "exact", "neural"])
def test_a_far_surface_facing_like_the_left_one_shadows(scene, path):
    mesh, grid, cells = scene
    offset = secondary.network_offset(mesh.size, grid.voxel_size)
    assert HEIGHT > 2 * SECONDARY_SELF_REACH * offset     # the lid lies far beyond the reach
    assert occluders(mesh, grid, cells)[path](*inside_the_box(offset)).all()


def test_without_the_reach_the_network_would_walk_through_the_lid(scene, monkeypatch):
    """The check above can fail: with no reach, the lid reads as the left surface."""
    mesh, grid, cells = scene
    offset = secondary.network_offset(mesh.size, grid.voxel_size)
    monkeypatch.setattr(secondary, "SECONDARY_SELF_REACH", 1e9)
    assert not occluders(mesh, grid, cells)["neural"](*inside_the_box(offset)).any()
