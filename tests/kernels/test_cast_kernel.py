"""The Warp mesh caster against brute force: same first triangle, same distance (float32)."""

import numpy as np
import pytest
import torch
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


@pytest.mark.parametrize("threads", [2, 3, 4])
def test_casts_split_over_threads_equal_brute_force_run_after_run(threads):
    """Launches of slices at once (``kernels.launches``), at a ray count that splits
    unevenly: the first hits of one launch and of brute force, every run."""
    from vdnif_addon.kernels import launches

    rng = np.random.default_rng(threads)
    soup, vertices, triangles = random_soup(rng, 400)
    origins, directions = random_rays(rng, 4 * launches.MIN_SLICE_POINTS + 7)
    limits = rng.random(len(origins)) * 2.5
    caster = MeshCaster(vertices, triangles)
    expected_index, expected_t = BruteForceCaster(soup).cast(origins, directions, limits)
    one = caster.cast(origins, directions, limits)
    assert launches.parts("cpu", len(origins), threads) == threads
    assert (one[0] >= 0).sum() > 300
    np.testing.assert_array_equal(one[0], expected_index)
    for _ in range(5):
        index, t = caster.cast(origins, directions, limits, threads)
        np.testing.assert_array_equal(index, one[0])
        np.testing.assert_array_equal(t, one[1])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_casts_on_cuda_equal_the_cpu():
    rng = np.random.default_rng(5)
    soup, vertices, triangles = random_soup(rng, 400)
    origins, directions = random_rays(rng, 3 * 2048 + 5)
    limits = rng.random(len(origins)) * 2.5
    cpu = MeshCaster(vertices, triangles).cast(origins, directions, limits)
    gpu = MeshCaster(vertices, triangles, "cuda:0").cast(origins, directions, limits, 4)
    assert (cpu[0] >= 0).sum() > 300
    np.testing.assert_array_equal(gpu[0], cpu[0])
    np.testing.assert_allclose(gpu[1], cpu[1], rtol=0, atol=1e-5)
