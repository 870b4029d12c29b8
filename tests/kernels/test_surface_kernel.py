"""The surface-hit kernel (``kernels.surface``) against hand-computed cases and against the
numpy pipeline it replaced (``tests/oracles/surface_casts.py``) with a float64 brute-force
caster as the independent reference."""

import sys

import numpy as np
import pytest
import warp as wp
from oracles import surface_casts as oracle
from oracles.geometry import BruteForceCaster

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import voxels, walk_rules
from vdnif_addon.geometry.restmesh import Albedo, RestMesh
from vdnif_addon.kernels import runtime, surface
from vdnif_addon.tracing import groundtruth, references

# Degenerate input must be handled explicitly: any numpy floating-point warning fails a test.
pytestmark = pytest.mark.filterwarnings("error")


@wp.kernel
def _weights(points: wp.array(dtype=wp.vec3d), corners: wp.array(dtype=wp.vec3d),
             out: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    out[i] = surface.barycentric(points[i], corners[3 * i], corners[3 * i + 1],
                                 corners[3 * i + 2])


def kernel_barycentric(points, corners):
    """The kernel's barycentric weights of points (N, 3) on triangles (N, 3, 3)."""
    runtime.load(sys.modules[__name__], "cpu")
    out = wp.empty(len(points), dtype=wp.vec3d)
    wp.launch(_weights, dim=len(points), inputs=[
        wp.array(np.asarray(points, np.float64), dtype=wp.vec3d),
        wp.array(np.asarray(corners, np.float64).reshape(-1, 3), dtype=wp.vec3d), out])
    return out.numpy()


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# --- barycentric weights ---------------------------------------------------------------------

def test_barycentric_recovers_weights_and_points_of_random_triangles():
    rng = np.random.default_rng(1)
    corners = rng.normal(size=(500, 3, 3))
    weights = rng.normal(size=(500, 3))
    weights /= weights.sum(axis=1, keepdims=True)    # points in the plane, also outside
    points = np.einsum("nc,nci->ni", weights, corners)
    normal = unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    lifted = points + rng.normal(size=(500, 1)) * normal   # off the plane: projected
    found = kernel_barycentric(lifted, corners)
    np.testing.assert_allclose(found, weights, atol=1e-8)
    np.testing.assert_allclose(found, oracle.barycentric(lifted, corners), atol=1e-12)


def test_barycentric_of_degenerate_triangles_is_finite_and_sensible():
    corners = np.array([
        [[0, 0, 0], [1, 0, 0], [2, 0, 0]],      # collinear: segment 0..2 along x
        [[0, 0, 0], [0, 0, 0], [0, 4, 0]],      # two corners coincide
        [[1, 1, 1], [1, 1, 1], [1, 1, 1]],      # a point
        [[0, 0, 0], [2, 0, 0], [1, 0, 0]],      # collinear, point beyond the segment
        [[0, 0, 0], [1, 0, 0], [3, 0, 0]],      # longest edge c -> a
    ], dtype=float)
    points = np.array([[1.5, 0, 0], [5, 1, 0], [3, 3, 3], [-1, 2, 0], [2.5, 1, 0]],
                      dtype=float)
    weights = kernel_barycentric(points, corners)
    assert np.all(np.isfinite(weights))
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    recomposed = np.einsum("nc,nci->ni", weights, corners)
    # The nearest point of each degenerate triangle (a segment or a point).
    np.testing.assert_allclose(recomposed, [[1.5, 0, 0], [0, 1, 0], [1, 1, 1], [0, 0, 0],
                                            [2.5, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(weights[2], [1 / 3, 1 / 3, 1 / 3])
    np.testing.assert_allclose(weights, oracle.barycentric(points, corners), atol=1e-12)


# --- hits on a square: weights, normals, distance --------------------------------------------

def square_caster(normals=None):
    """Unit square at z = 0: triangle 0 = (0,0)(1,0)(1,1), 1 = (0,0)(1,1)(0,1)."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    normals = np.tile(np.float32([0, 0, 1]), (2, 3, 1)) if normals is None else normals
    return surface.SurfaceCaster(vertices, triangles, normals)


def down_at(xy):
    """Rays from z = 1 straight down onto the points xy (N, 2)."""
    xy = np.asarray(xy, float)
    return (np.column_stack([xy, np.ones(len(xy))]), np.tile([0.0, 0, -1], (len(xy), 1)))


def test_square_hits_have_exact_triangle_distance_and_weights():
    caster = square_caster()
    origins, directions = down_at([[0.7, 0.2], [0.25, 0.75], [2, 2]])
    triangle, distance, weights, normal = caster.cast_rays(origins, directions, np.inf)
    assert triangle.tolist() == [0, 1, -1]
    np.testing.assert_allclose(distance, [1, 1, 0], atol=1e-15)
    # Triangle 0 at (x, y): weights (1 - x, x - y, y); triangle 1: (1 - y, x, y - x).
    np.testing.assert_allclose(weights, [[0.3, 0.5, 0.2], [0.25, 0.25, 0.5], [0, 0, 0]],
                               atol=1e-15)
    np.testing.assert_allclose(normal, [[0, 0, 1], [0, 0, 1], [0, 0, 0]])


def test_limits_bound_the_hits():
    caster = square_caster()
    origins, directions = down_at([[0.7, 0.2]] * 4)
    triangle, distance, _, _ = caster.cast_rays(origins, directions, [2.0, 0.999, -1.0, 1.001])
    assert triangle.tolist() == [0, -1, -1, 0]
    assert distance.tolist() == [1.0, 0.0, 0.0, 1.0]


def test_smooth_normals_are_interpolated_and_renormalized():
    normals = np.float32([[[0, 0, 1], [1, 0, 0], [0, 1, 0]], [[0, 0, 1]] * 3])
    # (0.5, 0): weights (0.5, 0.5, 0) on triangle 0; (0.2, 0.9): (0.1, 0.2, 0.7) on 1.
    _, _, weights, normal = square_caster(normals).cast_rays(*down_at([[0.5, 0.0001],
                                                                       [0.2, 0.9]]), np.inf)
    np.testing.assert_allclose(weights, [[0.5, 0.4999, 0.0001], [0.1, 0.2, 0.7]], atol=1e-12)
    expected = unit(np.array([[0.5, 0, 0.5001], [0, 0, 1]]))
    expected[0] = unit(np.array([0.4999, 0.0001, 0.5]))
    np.testing.assert_allclose(normal, expected, atol=1e-7)


def test_cancelling_normals_fall_back_to_the_face_normal():
    normals = np.float32([[[1, 0, 0]] * 3, [[0, 0, 1], [0, 0, -1], [0, 0, -1]]])
    # (0.25, 0.5) on triangle 1: weights (0.5, 0.25, 0.25), where its normals cancel.
    triangle, _, weights, normal = square_caster(normals).cast_rays(
        *down_at([[0.6, 0.3], [0.25, 0.5]]), np.inf)
    assert triangle.tolist() == [0, 1]
    np.testing.assert_allclose(weights[1], [0.5, 0.25, 0.25], atol=1e-15)
    np.testing.assert_allclose(normal, [[1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_refit_moves_the_surface_and_its_normals():
    caster = square_caster()
    vertices = np.array([[0, 0, 0.5], [1, 0, 0.5], [1, 1, 0.5], [0, 1, 0.5]])
    caster.refit(vertices, np.tile(np.float32([0, 1, 0]), (2, 3, 1)))
    triangle, distance, _, normal = caster.cast_rays(*down_at([[0.7, 0.2]]), np.inf)
    assert triangle.tolist() == [0]
    np.testing.assert_allclose(distance, [0.5], atol=1e-15)
    np.testing.assert_allclose(normal, [[0, 1, 0]])


def test_empty_mesh_and_no_rays():
    caster = surface.SurfaceCaster(np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros((0, 3, 3)))
    triangle, distance, weights, normal = caster.cast_rays(np.zeros((2, 3)), np.ones((2, 3)), 1)
    assert triangle.tolist() == [-1, -1] and not distance.any() and weights.shape == (2, 3)
    triangle, *_ = square_caster().cast_segments(np.zeros((0, 3)), np.zeros((0, 3)),
                                                 np.zeros(0, int), 0.0)
    assert triangle.shape == (0,)


# --- against the numpy pipeline on a random mesh ---------------------------------------------

def blob_mesh(seed=0, resolution=24):
    """A lumpy closed surface (a UV sphere with random radii), smooth normals, 2 materials."""
    rng = np.random.default_rng(seed)
    theta, phi = np.meshgrid(np.linspace(0.1, np.pi - 0.1, resolution),
                             np.linspace(0, 2 * np.pi, 2 * resolution, endpoint=False),
                             indexing="ij")
    radius = 1 + 0.15 * rng.normal(size=theta.shape)
    vertices = np.stack([radius * np.sin(theta) * np.cos(phi),
                         radius * np.sin(theta) * np.sin(phi), radius * np.cos(theta)],
                        -1).reshape(-1, 3)
    ring = 2 * resolution
    triangles = []
    for i in range(resolution - 1):
        for j in range(ring):
            a, b = i * ring + j, i * ring + (j + 1) % ring
            c, d = a + ring, b + ring
            triangles += [(a, c, b), (b, c, d)]
    triangles = np.array(triangles, np.int32)
    normals = unit(vertices)[triangles].astype(np.float32)
    material = (vertices[triangles].mean(1)[:, 0] > 0).astype(np.int32)
    albedo = [Albedo("constant", np.float32(c)) for c in ((1, 0, 0), (0, 0, 1))]
    return RestMesh(name="Blob", vertices=vertices, triangles=triangles,
                    corner_normals=normals, material_index=material, albedo=albedo)


def assert_hits_equal(found, expected, size, min_hits=100):
    """Same hits and triangles as the float64 brute force; distance, weights and normals
    of the float64 refinement equal its exact values to rounding."""
    assert expected.hit.sum() >= min_hits and (~expected.hit).sum() >= min_hits
    np.testing.assert_array_equal(found.triangle, expected.triangle)
    hit = expected.hit
    np.testing.assert_allclose(found.distance, expected.distance, atol=1e-9 * size)
    np.testing.assert_allclose(found.weights[hit], expected.weights[hit], atol=1e-9)
    np.testing.assert_allclose(found.normal[hit], expected.normal[hit], atol=1e-9)
    np.testing.assert_array_equal(found.albedo, expected.albedo)
    np.testing.assert_array_equal(found.material, expected.material)
    assert not found.weights[~hit].any() and not found.normal[~hit].any()


def test_rays_equal_the_numpy_pipeline_with_brute_force():
    mesh = blob_mesh()
    rng = np.random.default_rng(3)
    origins = 3 * unit(rng.normal(size=(3000, 3)))
    directions = unit(rng.uniform(-1, 1, (3000, 3)) - origins)
    found = groundtruth.cast_surface(mesh, groundtruth.rest_surface(mesh), origins,
                                     directions, np.inf)
    brute = BruteForceCaster(mesh.vertices[mesh.triangles])
    assert_hits_equal(found, oracle.cast_surface(mesh, brute, origins, directions,
                                                 np.full(3000, np.inf)), mesh.size)


def cell_segments(grid, rng, count):
    """Random segments inside random cells; a quarter start on a cell face (where the
    margin matters) and a few have zero length."""
    cell = rng.integers(len(grid.cells), size=count)
    low, high = grid.cell_bounds(cell)
    p0 = low + rng.random((count, 3)) * (high - low)
    p1 = low + rng.random((count, 3)) * (high - low)
    on_face = rng.random(count) < 0.25
    axis = rng.integers(3, size=count)
    rows = np.flatnonzero(on_face)
    side = np.where(rng.random(count) < 0.5, low[np.arange(count), axis],
                    high[np.arange(count), axis])
    p0[rows, axis[rows]] = side[rows]
    p1[:5] = p0[:5]
    return walk_rules.Segments(ray=np.arange(count), cell=cell, t0=np.zeros(count),
                             t1=np.ones(count), p0=p0, p1=p1)


@pytest.mark.parametrize("by_cell", [True, False])
def test_segments_equal_the_numpy_pipeline_with_brute_force(by_cell):
    """The per-cell triangle lists hold every triangle a segment of the cell can hit."""
    mesh = blob_mesh(seed=1)
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 12)
    segments = cell_segments(grid, np.random.default_rng(4), 20000)
    caster = groundtruth.rest_surface(mesh, grid if by_cell else None)
    found = groundtruth.segment_targets(mesh, caster, segments)
    brute = BruteForceCaster(mesh.vertices[mesh.triangles])
    expected = oracle.segment_targets(mesh, brute, segments)
    assert not found.hit[:5].any()
    assert_hits_equal(found, expected, mesh.size)


def test_a_surface_just_beyond_the_cell_face_is_hit_within_the_margin():
    """A triangle half a margin outside cell 0 meets no point of it: cell 0 still lists it,
    and its segment ending on that face reports the hit at its end."""
    margin = 1e-3
    vertices = np.array([[1 + margin / 2, -1, -1], [1 + margin / 2, 3, -1],
                         [1 + margin / 2, -1, 3]])
    boxes = (np.array([[0.0, 0, 0], [1, 0, 0]]), np.array([[1.0, 1, 1], [2, 1, 1]]))
    caster = surface.SurfaceCaster(vertices, [[0, 1, 2]], np.tile(np.float32([1, 0, 0]),
                                                                  (1, 3, 1)),
                                   cell_boxes=boxes, cell_margin=2 * margin)
    p0 = np.array([[0.5, 0.5, 0.5], [0.2, 0.5, 0.5], [1.5, 0.5, 0.5]])
    p1 = np.array([[1.0, 0.5, 0.5], [0.9, 0.5, 0.5], [1.0, 0.5, 0.5]])
    triangle, distance, _, _ = caster.cast_segments(p0, p1, [0, 0, 1], margin)
    assert triangle.tolist() == [0, -1, 0]
    np.testing.assert_allclose(distance, [0.5, 0, 0.5 - margin / 2], atol=1e-12)


def test_segment_cells_outside_the_caster_and_refits_are_refused():
    mesh = blob_mesh()
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 6)
    caster = groundtruth.rest_surface(mesh, grid)
    segments = cell_segments(grid, np.random.default_rng(0), 10)
    segments.cell[3] = len(grid.cells)
    with pytest.raises(VDNIFError, match="cells"):
        groundtruth.segment_targets(mesh, caster, segments)
    with pytest.raises(VDNIFError, match="cannot be refit"):
        caster.refit(mesh.vertices, mesh.corner_normals)


def test_true_reference_is_the_cast_of_its_pose():
    mesh = blob_mesh()
    caster = groundtruth.rest_surface(mesh)
    moved = mesh.vertices * [1.2, 0.8, 1.0] + [0.1, 0, 0]
    caster.refit(moved, mesh.corner_normals)
    rng = np.random.default_rng(5)
    origins = 3 * unit(rng.normal(size=(2000, 3)))
    directions = unit(rng.uniform(-1, 1, (2000, 3)) - origins)
    passes = references.true_reference(mesh, caster, origins, directions)
    brute = BruteForceCaster(moved[mesh.triangles])
    expected = oracle.cast_surface(mesh, brute, origins, directions, np.full(2000, np.inf),
                                   vertices=moved)
    np.testing.assert_array_equal(passes.hit, expected.hit)
    np.testing.assert_allclose(passes.distance, expected.distance, atol=1e-9)
    np.testing.assert_allclose(passes.normal, expected.normal, atol=1e-9)


@pytest.mark.skipif(not runtime.init().is_cuda_available(), reason="needs CUDA")
def test_cuda_casts_equal_the_cpu():
    mesh = blob_mesh(seed=2)
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 12)
    segments = cell_segments(grid, np.random.default_rng(6), 20000)
    results = [surface.SurfaceCaster(
        mesh.vertices, mesh.triangles, mesh.corner_normals, device,
        cell_boxes=grid.cell_bounds(np.arange(len(grid.cells))), cell_margin=1e-5)
        .cast_segments(segments.p0, segments.p1, segments.cell, 1e-6) for device in
        ("cpu", "cuda:0")]
    np.testing.assert_array_equal(results[0][0], results[1][0])
    for cpu, cuda in zip(results[0][1:], results[1][1:]):
        np.testing.assert_allclose(cpu, cuda, atol=1e-9)
