"""The Warp mesh caster against brute force: same first triangle, same distance (float32)."""

import numpy as np
from oracles.geometry import BruteForceCaster

from vdnif_addon.kernels.cast import MeshCaster


def random_soup(rng, count=150):
    triangles = rng.random((count, 3, 3))
    return triangles, triangles.reshape(-1, 3), np.arange(3 * count).reshape(-1, 3)


def random_rays(rng, count=4000):
    origins = rng.random((count, 3)) * 3 - 1
    directions = rng.normal(size=(count, 3))
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def test_first_hits_equal_brute_force():
    rng = np.random.default_rng(0)
    soup, vertices, triangles = random_soup(rng)
    origins, directions = random_rays(rng)
    limits = rng.random(len(origins)) * 2.5
    limits[:10] = -1.0                                   # a negative limit casts nothing
    index, t = MeshCaster(vertices, triangles).cast(origins, directions, limits)
    expected_index, expected_t = BruteForceCaster(soup).cast(origins, directions, limits)
    assert (index >= 0).sum() > 100 and not (index[:10] >= 0).any()
    np.testing.assert_array_equal(index, expected_index)
    hit = index >= 0
    np.testing.assert_allclose(t[hit], expected_t[hit], atol=1e-5)
    assert np.isinf(t[~hit]).all()


def test_refit_follows_moved_vertices():
    rng = np.random.default_rng(1)
    soup, vertices, triangles = random_soup(rng)
    origins, directions = random_rays(rng)
    caster = MeshCaster(vertices, triangles)
    moved = soup * 0.7 + np.array([0.4, -0.2, 0.1]) + 0.05 * rng.normal(size=soup.shape)
    caster.refit(moved.reshape(-1, 3))
    index, t = caster.cast(origins, directions, np.full(len(origins), np.inf))
    expected_index, expected_t = BruteForceCaster(moved).cast(origins, directions,
                                                              np.full(len(origins), np.inf))
    np.testing.assert_array_equal(index, expected_index)
    np.testing.assert_allclose(t[index >= 0], expected_t[index >= 0], atol=1e-5)


def test_empty_mesh_and_no_rays():
    caster = MeshCaster(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    index, t = caster.cast(np.zeros((3, 3)), np.ones((3, 3)), np.ones(3))
    assert (index == -1).all() and np.isinf(t).all()
    index, t = MeshCaster(*random_soup(np.random.default_rng(2))[1:]).cast(
        np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    assert index.shape == (0,) and t.shape == (0,)
