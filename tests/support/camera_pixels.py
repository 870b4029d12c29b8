"""Blender's own projection as the reference of camera rays (imports nothing of the core)."""

import numpy as np


def assert_rays_hit_their_pixels(scene, camera, origins, directions, width, height):
    """Each ray (row-major from the top left) passes through its pixel's centre as
    ``world_to_camera_view`` projects a point along it (normalized, y up)."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    projected = np.array([world_to_camera_view(scene, camera, Vector(o + 5 * d))[:2]
                          for o, d in zip(origins, directions)])
    column, row = np.meshgrid(np.arange(width), np.arange(height))
    expected = np.stack([(column.ravel() + 0.5) / width, 1 - (row.ravel() + 0.5) / height], 1)
    np.testing.assert_allclose(projected, expected, atol=1e-6)
