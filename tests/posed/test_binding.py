"""The surface binding (posed.binding) against motions whose answer is known: rest, a
translation, a rotation, an affine map and a bend, and its continuity between voxel
corners."""

import numpy as np
import pytest


def sphere(count=400, seed=0):
    """Points on the unit sphere (Fibonacci spiral) and their normals (themselves)."""
    i = np.arange(count) + 0.5
    phi = np.arccos(1 - 2 * i / count)
    theta = np.pi * (1 + 5 ** 0.5) * i
    points = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    return points, points.copy()


def shell_points(seed=1, count=500):
    """Points within 0.2 of the unit sphere, inside and out, as voxel corners lie."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return direction * rng.uniform(0.8, 1.2, (count, 1))


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_rest_translation_and_rotation_are_followed(core):
    binding = core("posed.binding")
    vertices, normals = sphere()
    points = shell_points()
    bound = binding.bind(points, vertices, normals, scale=0.1)
    np.testing.assert_allclose(bound.moved(vertices, normals), points, atol=1e-12)
    shift = np.array([0.3, -1.0, 2.0])
    np.testing.assert_allclose(bound.moved(vertices + shift, normals), points + shift,
                               atol=1e-12)
    turn = rotation((1, 2, 0.5), 0.8)
    moved = bound.moved(vertices @ turn.T + shift, normals @ turn.T)
    error = np.linalg.norm(moved - (points @ turn.T + shift), axis=1).max()
    # the regularisation's pull toward the identity: ~1e-3 of the angle times 0.2
    assert error < 1e-3 * 0.8 * 0.2


def test_a_bend_is_followed_smoothly_off_the_surface(core):
    """A tube bent about its middle (each vertex rotated by an angle that grows along the
    tube): points inside and outside follow the bend as the same map moves them, to a
    small part of their distance from the surface, and points a hundredth of a voxel
    apart move a hundredth of a voxel apart (no jumps where the neighbour sets change)."""
    binding = core("posed.binding")
    u, v = np.meshgrid(np.linspace(0, 4, 81), np.linspace(0, 2 * np.pi, 24, endpoint=False))
    vertices = np.stack([u.ravel(), 0.5 * np.cos(v.ravel()), 0.5 * np.sin(v.ravel())], 1)
    normals = np.stack([0 * u.ravel(), np.cos(v.ravel()), np.sin(v.ravel())], 1)

    def bend(p):
        angle = 0.6 * np.clip(p[:, 0] - 1.5, 0, 1)          # up to 0.6 rad past x = 2.5
        c, s = np.cos(angle), np.sin(angle)
        pivot = np.array([2.0, 0.0, 0.0])
        q = p - pivot
        return np.stack([c * q[:, 0] - s * q[:, 1], s * q[:, 0] + c * q[:, 1], q[:, 2]], 1) \
            + pivot

    rng = np.random.default_rng(3)
    radius = rng.uniform(0.3, 0.7, 400)
    around = rng.uniform(0, 2 * np.pi, 400)
    points = np.stack([rng.uniform(0.5, 3.5, 400), radius * np.cos(around),
                       radius * np.sin(around)], 1)
    bound = binding.bind(points, vertices, normals, scale=0.1)
    posed_normals = bend(vertices + 1e-4 * normals) - bend(vertices)
    posed_normals /= np.linalg.norm(posed_normals, axis=1, keepdims=True)
    moved = bound.moved(bend(vertices), posed_normals)
    error = np.linalg.norm(moved - bend(points), axis=1)
    assert error.max() < 0.02, error.max()                 # of a 4-unit tube, 0.2 off it
    step = np.array([1e-3, 0, 0])
    nudged = binding.bind(points + step, vertices, normals, scale=0.1).moved(
        bend(vertices), posed_normals)
    jump = np.linalg.norm(nudged - moved, axis=1).max()
    assert jump < 3e-3, jump


def test_a_topology_change_is_refused(core):
    binding = core("posed.binding")
    vertices, normals = sphere(50)
    bound = binding.bind(shell_points(count=10), vertices, normals, scale=0.1)
    with pytest.raises(core("errors").VDNIFError, match="49 vertices in this pose and 50"):
        bound.moved(vertices[:-1], normals[:-1])


def test_vertex_normals_of_a_tetrahedron_point_outward(core):
    binding = core("posed.binding")
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    normals = binding.vertex_normals(vertices, triangles)
    centre = vertices.mean(0)
    assert ((normals * (vertices - centre)).sum(1) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1)


def test_the_nearest_vertices_do_not_depend_on_the_search_blocks(core, monkeypatch):
    """The search holds a bounded number of distances at once (a million-vertex surface
    takes a few points a block): any block size gives the same neighbours, distances and
    radii as one block holding every point."""
    binding = core("posed.binding")
    rng = np.random.default_rng(3)
    points, vertices = rng.normal(size=(37, 3)), rng.normal(size=(500, 3))
    monkeypatch.setattr(binding, "_BLOCK_VALUES", 37 * 500)
    whole = binding._nearest(points, vertices, 8)
    for values in (1, 499, 501, 3 * 500):
        monkeypatch.setattr(binding, "_BLOCK_VALUES", values)
        for got, expected in zip(binding._nearest(points, vertices, 8), whole):
            np.testing.assert_array_equal(got, expected)
