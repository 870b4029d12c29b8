"""Thickness of a closed rest mesh (``kernels.thickness``): each triangle's solid measured
along its inward normal, on boxes whose answers are their side lengths (no bpy)."""

import math

import numpy as np
import pytest

from vdnif_addon.kernels.thickness import thin_thickness, triangle_thickness


def box(sizes):
    """(vertices, triangles) of an axis-aligned box with outward winding."""
    a, b, c = sizes
    vertices = np.array([[x, y, z] for z in (0, c) for y in (0, b) for x in (0, a)], float)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2),
             (1, 3, 7, 5)]
    triangles = np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    return vertices, triangles


def signed_volume(vertices, triangles):
    p = vertices[triangles]
    return np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6


def test_thickness_is_the_solid_along_each_inward_normal():
    sizes = np.array([1.0, 0.6, 0.05])
    vertices, triangles = box(sizes)
    assert signed_volume(vertices, triangles) == pytest.approx(np.prod(sizes))  # outward
    thickness, area = triangle_thickness(vertices, triangles)
    corners = vertices[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    axis = np.abs(normals).argmax(axis=1)                  # each face's normal axis
    assert thickness == pytest.approx(sizes[axis], rel=1e-4)
    assert area.sum() == pytest.approx(2 * (1.0 * 0.6 + 1.0 * 0.05 + 0.6 * 0.05))
    # The two large faces are 1.2 / 1.36 of the area: thinner than 0.05 nowhere, and at
    # 0.05 for any share up to theirs; the thickest share is the box's length.
    large = 2 * 1.0 * 0.6 / area.sum()
    assert thin_thickness(thickness, area, 0.01) == pytest.approx(0.05, rel=1e-4)
    assert thin_thickness(thickness, area, large - 0.01) == pytest.approx(0.05, rel=1e-4)
    assert thin_thickness(thickness, area, 0.999) == pytest.approx(1.0, rel=1e-4)


def test_an_open_sheet_or_inward_normals_measure_no_thickness():
    vertices, triangles = box([1.0, 1.0, 1.0])
    flipped = triangles[:, ::-1]                             # normals pointing in
    thickness, area = triangle_thickness(vertices, flipped)
    assert np.isinf(thickness).all()
    assert math.isinf(thin_thickness(thickness, area, 0.01))
    sheet = triangles[:2]                                    # one face alone
    assert np.isinf(triangle_thickness(vertices, sheet)[0]).all()
