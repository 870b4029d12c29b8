"""Voxelization and the inversion test, checked against independent references.

Occupancy is compared with a brute-force reference that clips every triangle against every
cell's closed box (Sutherland-Hodgman), which shares nothing with the module's
separating-axis test; Jacobian determinants with finite differences of the trilinear map.
"""

import itertools
import pathlib
import warnings

import numpy as np
import pytest
from obj_files import read_obj

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import voxels

BUNNY = pathlib.Path(__file__).resolve().parents[2] / "assets" / "meshes" / "stanford-bunny.obj"


def polygon_meets_box(polygon, low, high):
    """Does the convex polygon (list of 3-tuples) meet the closed box [low, high]?

    Sutherland-Hodgman: clip by the six closed half-spaces; something remains iff they meet.
    """
    for axis, side in itertools.product(range(3), (-1, 1)):
        bound = high[axis] if side > 0 else low[axis]
        clipped = []
        for current, following in zip(polygon, polygon[1:] + polygon[:1]):
            outside_current = side * (current[axis] - bound)
            outside_following = side * (following[axis] - bound)
            if outside_current <= 0:
                clipped.append(current)
            if outside_current * outside_following < 0:
                t = outside_current / (outside_current - outside_following)
                clipped.append(tuple(c + t * (f - c) for c, f in zip(current, following)))
        polygon = clipped
        if not polygon:
            return False
    return True


def brute_force_cells(grid, vertices, triangles):
    """Set of ijk tuples of every grid cell whose grown closed box a triangle meets.

    Every cell of the grid is considered; an AABB comparison only skips cells the clipping
    would reject anyway.
    """
    all_cells = np.stack(np.meshgrid(*map(np.arange, grid.dims), indexing="ij"), -1).reshape(-1, 3)
    low = all_cells - voxels.BOX_TOLERANCE
    high = all_cells + 1 + voxels.BOX_TOLERANCE
    occupied = set()
    for triangle in (vertices[triangles] - grid.origin) / grid.voxel_size:
        near = ((low <= triangle.max(0)) & (high >= triangle.min(0))).all(axis=1)
        polygon = [tuple(point) for point in triangle]
        for cell, cell_low, cell_high in zip(all_cells[near], low[near], high[near]):
            if polygon_meets_box(polygon, cell_low, cell_high):
                occupied.add(tuple(cell))
    return occupied


def cell_set(grid):
    return set(map(tuple, grid.cells.tolist()))


def soup(rng, count, scale=1.0, offset=0.0):
    """(3*count, 3) vertices and (count, 3) triangles of unconnected random triangles."""
    vertices = offset + scale * rng.uniform(size=(3 * count, 3))
    return vertices, np.arange(3 * count).reshape(count, 3)


@pytest.fixture(scope="module")
def bunny():
    vertices, triangles = read_obj(BUNNY)
    return vertices, triangles[::4]


# --- occupancy against the brute-force reference -------------------------------------------


def test_random_soups_match_brute_force():
    rng = np.random.default_rng(7)
    vertices, triangles = soup(rng, 12)
    grid = voxels.build_grid(vertices, triangles, 5)
    assert cell_set(grid) == brute_force_cells(grid, vertices, triangles)

    # Small and large slanted triangles on an anisotropic, far-off-origin object.
    small, small_triangles = soup(rng, 20, scale=0.15)
    large, large_triangles = soup(rng, 4)
    vertices = np.concatenate([small + rng.uniform(size=(1, 3)), large]) * [3, 1, 0.5] + 100
    triangles = np.concatenate([small_triangles, large_triangles + len(small)])
    grid = voxels.build_grid(vertices, triangles, 7)
    assert cell_set(grid) == brute_force_cells(grid, vertices, triangles)


def test_grid_aligned_soup_matches_brute_force():
    # Coordinates on a half-voxel lattice: many triangles touch cell faces, edges and corners
    # exactly, which checks that both sides treat boxes as closed in the same way.
    rng = np.random.default_rng(3)
    vertices = rng.integers(0, 17, size=(45, 3)) / 2.0
    vertices[:2] = [[0, 0, 0], [8, 8, 8]]  # AABB [0, 8]^3 at R = 8: h = 1, origin -1
    triangles = np.arange(45).reshape(15, 3)
    grid = voxels.build_grid(vertices, triangles, 8)
    assert grid.voxel_size == 1.0 and np.array_equal(grid.origin, [-1, -1, -1])
    assert cell_set(grid) == brute_force_cells(grid, vertices, triangles)


def test_degenerate_triangles_match_brute_force():
    rng = np.random.default_rng(11)
    start, end = rng.uniform(size=(2, 6, 3))
    segments = np.stack([start, end, start + 0.3 * (end - start)], axis=1)  # collinear
    repeated = np.stack([start, end, end], axis=1)  # two equal vertices
    points = np.repeat(rng.uniform(size=(6, 1, 3)), 3, axis=1)  # all three equal
    vertices = np.concatenate([segments, repeated, points]).reshape(-1, 3)
    triangles = np.arange(len(vertices)).reshape(-1, 3)
    grid = voxels.build_grid(vertices, triangles, 6)
    expected = brute_force_cells(grid, vertices, triangles)
    assert cell_set(grid) == expected
    assert len(expected) > 6  # the segments really reach across cells


def test_bunny_matches_brute_force(bunny):
    vertices, triangles = bunny
    grid = voxels.build_grid(vertices, triangles, 16)
    assert cell_set(grid) == brute_force_cells(grid, vertices, triangles)


def test_chunking_and_candidate_pruning_do_not_change_the_result(monkeypatch):
    rng = np.random.default_rng(5)
    vertices, triangles = soup(rng, 10)
    expected = voxels.build_grid(vertices, triangles, 12).cells
    monkeypatch.setattr(voxels, "PAIRS_PER_CHUNK", 7)
    assert np.array_equal(voxels.build_grid(vertices, triangles, 12).cells, expected)
    # Far wider candidate ranges only give the separating-axis test more cells to reject.
    monkeypatch.setattr(voxels, "PAIRS_PER_CHUNK", 1 << 14)
    monkeypatch.setattr(voxels, "CANDIDATE_MARGIN", 1.5)
    assert np.array_equal(voxels.build_grid(vertices, triangles, 12).cells, expected)


# --- thin parts and exact contact ----------------------------------------------------------


def cells_of_samples(grid, vertices, triangle, count=20000, seed=0):
    """Set of ijk of the cells containing random points of one triangle (3,) int."""
    weights = np.random.default_rng(seed).dirichlet(np.ones(3), size=count)
    samples = weights @ vertices[triangle]
    return set(map(tuple, np.floor((samples - grid.origin) / grid.voxel_size).astype(int)))


def test_needle_thin_triangle_misses_no_voxel():
    direction = np.array([1.0, 1.0, 0.9])
    vertices = np.array([[0, 0, 0], direction, direction + [1e-4, -1e-4, 0]])
    triangles = np.array([[0, 1, 2]])
    grid = voxels.build_grid(vertices, triangles, 12)
    occupied = cell_set(grid)
    assert cells_of_samples(grid, vertices, triangles[0]) <= occupied
    assert occupied == brute_force_cells(grid, vertices, triangles)


def test_paper_thin_plate_gets_two_layers_and_misses_no_voxel():
    vertices = np.array([[0, 0, 0.3], [1, 0, 0.3], [1, 0.7, 0.3], [0, 0.7, 0.3]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    grid = voxels.build_grid(vertices, triangles, 8)
    assert grid.dims.tolist() == [10, 7, 2]
    occupied = cell_set(grid)
    for triangle in triangles:
        assert cells_of_samples(grid, vertices, triangle) <= occupied
    # The plate lies in the plane between the two layers: both are occupied, identically.
    layers = [{ijk[:2] for ijk in occupied if ijk[2] == k} for k in (0, 1)]
    assert layers[0] == layers[1] and len(layers[0]) > 40
    assert occupied == brute_force_cells(grid, vertices, triangles)


def test_triangles_on_cell_faces_edges_and_corners_mark_every_touching_cell():
    # Two point triangles fix the AABB to [0, 8]^3 at R = 8: h = 1, grid planes at integers.
    vertices = np.array(
        [
            [0, 0, 0], [8, 8, 8],
            [3, 2.2, 2.2], [3, 2.8, 2.2], [3, 2.2, 2.8],  # in the plane x = 3
            [3, 3, 2.2], [3, 3, 2.8], [3.5, 3.4, 2.5],  # one edge on the line x = y = 3
        ]
    )  # fmt: skip
    triangles = np.array([[0, 0, 0], [1, 1, 1], [2, 3, 4], [5, 6, 7]])
    grid = voxels.build_grid(vertices, triangles, 8)
    assert np.array_equal(grid.origin, [-1, -1, -1]) and grid.voxel_size == 1
    corner_cells = {*itertools.product((0, 1), repeat=3), *itertools.product((8, 9), repeat=3)}
    on_face = {(3, 3, 3), (4, 3, 3)}
    on_edge = {(3, 3, 3), (3, 4, 3), (4, 3, 3), (4, 4, 3)}
    assert cell_set(grid) == corner_cells | on_face | on_edge


# --- sparse structure ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def bunny_grid(bunny):
    return voxels.build_grid(*bunny, 16)


def test_cells_are_sorted_by_linear_index(bunny_grid):
    i, j, k = bunny_grid.cells.T.astype(np.int64)
    linear = i + bunny_grid.dims[0] * (j + bunny_grid.dims[1] * k)
    assert np.all(np.diff(linear) > 0)
    assert bunny_grid.cells.dtype == np.int32 and bunny_grid.neighbours.dtype == np.int32


def test_neighbour_table_matches_lookup_and_is_symmetric(bunny_grid):
    grid = bunny_grid
    index_of = {tuple(cell): n for n, cell in enumerate(grid.cells.tolist())}
    steps = [(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)]
    expected = [
        [index_of.get(tuple(np.add(cell, step)), -1) for step in steps]
        for cell in grid.cells.tolist()
    ]
    assert np.array_equal(grid.neighbours, expected)
    for direction in range(6):
        has = grid.neighbours[:, direction] >= 0
        back = grid.neighbours[grid.neighbours[has, direction], direction ^ 1]
        assert np.array_equal(back, np.flatnonzero(has))
    assert (grid.neighbours == -1).any() and (grid.neighbours >= 0).any()


def test_neighbours_outside_the_grid_are_empty():
    # A plate fills its two z layers entirely along x and y, up to the grid's edges.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    grid = voxels.build_grid(vertices, np.array([[0, 1, 2], [0, 2, 3]]), 4)
    assert len(grid.cells) == grid.dims.prod()
    for direction, (axis, side) in enumerate(itertools.product(range(3), (0, 1))):
        at_edge = grid.cells[:, axis] == (grid.dims[axis] - 1 if side else 0)
        assert np.all(grid.neighbours[at_edge, direction] == -1)
        assert np.all(grid.neighbours[~at_edge, direction] >= 0)


def test_corners_are_unique_and_placed_at_cell_corners(bunny_grid):
    grid = bunny_grid
    assert len(np.unique(grid.corners, axis=0)) == len(grid.corners)
    assert np.array_equal(np.unique(grid.cell_corners), np.arange(len(grid.corners)))
    offsets = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])
    expected = grid.origin + (grid.cells[:, None, :] + offsets) * grid.voxel_size
    np.testing.assert_allclose(grid.corner_positions()[grid.cell_corners], expected, atol=1e-15)
    low, high = grid.cell_bounds(np.arange(len(grid.cells)))
    np.testing.assert_allclose(low, expected[:, 0], atol=1e-15)
    np.testing.assert_allclose(high, expected[:, 7], atol=1e-15)


# --- grid geometry -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "scale, offset, resolution",
    [
        ((1, 1, 1), 0, 4),
        ((3, 0.2, 1), -5, 32),
        ((0.01, 0.05, 0.02), 1000, 13),
        ((1, 1, 1e-3), 0, 256),
    ],
)
def test_grid_is_padded_centred_and_normalized(scale, offset, resolution):
    vertices, triangles = soup(np.random.default_rng(2), 6, scale=np.array(scale), offset=offset)
    grid = voxels.build_grid(vertices, triangles, resolution)
    size = vertices.max(0) - vertices.min(0)
    h = size.max() / resolution
    assert grid.voxel_size == pytest.approx(h, rel=1e-12)
    assert grid.dims[np.argmax(size)] == resolution + 2 and grid.resolution == resolution
    assert np.array_equal(grid.dims, np.floor(size / h + 1e-9).astype(int) + 2)
    centre = (vertices.max(0) + vertices.min(0)) / 2
    np.testing.assert_allclose(grid.origin + grid.dims * h / 2, centre)
    margin_low = vertices.min(0) - grid.origin
    margin_high = grid.origin + grid.dims * h - vertices.max(0)
    assert np.all(np.minimum(margin_low, margin_high) >= h / 2 - 1e-9 * h)
    normalized = grid.normalize(vertices)
    assert np.all((normalized > 0) & (normalized < 1))
    assert grid.extent == pytest.approx(h * (resolution + 2))


def test_only_vertices_of_triangles_set_the_grid():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [50, 50, 50]], dtype=float)
    grid = voxels.build_grid(vertices, np.array([[0, 1, 2]]), 4)
    assert grid.voxel_size == 0.25 and grid.dims.tolist() == [6, 6, 2]


# --- Jacobian determinants and inverted cells ----------------------------------------------


def trilinear_jacobian_determinants(cell_points):
    """(N, 8) determinants by central differences of the trilinear map of cells (N, 8, 3)."""
    offsets = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=float)

    def trilinear(uvw):  # (3,) parameter -> (N, 3) points
        weights = np.prod(np.where(offsets == 1, uvw, 1 - uvw), axis=1)
        return np.einsum("c,ncx->nx", weights, cell_points)

    step = 1e-3  # exact up to rounding: the map is linear along each parameter axis
    result = np.empty(cell_points.shape[:2])
    for corner, uvw in enumerate(offsets):
        columns = [
            (trilinear(uvw + step * e) - trilinear(uvw - step * e)) / (2 * step) for e in np.eye(3)
        ]
        result[:, corner] = np.linalg.det(np.stack(columns, axis=2))
    return result


@pytest.fixture(scope="module")
def small_grid():
    vertices, triangles = soup(np.random.default_rng(4), 8)
    return voxels.build_grid(vertices, triangles, 6)


def test_undeformed_cells_have_determinant_h_cubed(small_grid):
    dets = voxels.cell_jacobian_determinants(small_grid.corner_positions(),
                                             small_grid.cell_corners)
    assert dets.shape == (len(small_grid.cells), 8)
    np.testing.assert_allclose(dets, small_grid.voxel_size**3, rtol=1e-9)
    assert not voxels.inverted_cells(small_grid.corner_positions(), small_grid.cell_corners).any()


def test_affine_map_scales_determinants_by_its_determinant(small_grid):
    rng = np.random.default_rng(8)
    linear = rng.normal(size=(3, 3)) + 2 * np.eye(3)
    for matrix in (linear, linear @ np.diag([1, 1, -1])):
        moved = small_grid.corner_positions() @ matrix.T + rng.normal(size=3)
        dets = voxels.cell_jacobian_determinants(moved, small_grid.cell_corners)
        expected = np.linalg.det(matrix) * small_grid.voxel_size**3
        np.testing.assert_allclose(dets, expected, rtol=1e-9)
        inverted = voxels.inverted_cells(moved, small_grid.cell_corners)
        assert np.all(inverted == (expected < 0))


def test_determinants_match_finite_differences_of_the_trilinear_map(small_grid):
    rng = np.random.default_rng(9)
    h = small_grid.voxel_size
    moved = small_grid.corner_positions() + rng.normal(scale=0.3 * h,
                                                       size=small_grid.corners.shape)
    dets = voxels.cell_jacobian_determinants(moved, small_grid.cell_corners)
    expected = trilinear_jacobian_determinants(moved[small_grid.cell_corners])
    np.testing.assert_allclose(dets, expected, rtol=1e-6, atol=1e-9 * h**3)
    inverted = voxels.inverted_cells(moved, small_grid.cell_corners)
    assert np.array_equal(inverted, (expected <= 0).any(axis=1))


def test_mirrored_collapsed_and_flattened_cells_are_inverted():
    h = 0.5
    cube = h * np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=float)
    cell_corners = np.arange(8)[None]
    mirrored = cube * [-1, 1, 1]
    collapsed = cube.copy()
    collapsed[7] = collapsed[0]  # the far corner pushed onto the near one
    flattened = cube * [1, 1, 0]
    for corners in (mirrored, collapsed, flattened):
        assert voxels.inverted_cells(corners, cell_corners).tolist() == [True]
    assert voxels.inverted_cells(cube, cell_corners).tolist() == [False]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_corners_mark_their_cells_inverted_without_warnings(small_grid, bad):
    moved = small_grid.corner_positions()
    broken_corner = small_grid.cell_corners[0, 5]
    moved[broken_corner] = [bad, 0.0, bad]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inverted = voxels.inverted_cells(moved, small_grid.cell_corners)
        voxels.cell_jacobian_determinants(moved, small_grid.cell_corners)
    assert inverted.dtype == bool
    assert np.array_equal(inverted, (small_grid.cell_corners == broken_corner).any(axis=1))


# --- bad input ------------------------------------------------------------------------------

TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)


@pytest.mark.parametrize(
    "vertices, triangles, resolution, words",
    [
        (np.zeros((0, 3)), [[0, 1, 2]], 8, "no vertices"),
        (TRIANGLE, np.zeros((0, 3), dtype=int), 8, "no triangles"),
        (TRIANGLE[:, :2], [[0, 1, 2]], 8, "shape"),
        (TRIANGLE, [[0, 1]], 8, "shape"),
        (TRIANGLE, [[0.0, 1.0, 2.0]], 8, "integers"),
        (np.where([[0], [1], [0]], np.nan, TRIANGLE), [[0, 1, 2]], 8, "non-finite"),
        (np.where([[0], [0], [1]], np.inf, TRIANGLE), [[0, 1, 2]], 8, "non-finite"),
        (np.ones((3, 3)), [[0, 1, 2]], 8, "zero size"),
        (TRIANGLE, [[0, 1, 3]], 8, "index 3 out of range"),
        (TRIANGLE, [[0, -1, 2]], 8, "index -1 out of range"),
        (TRIANGLE, [[0, 1, 2]], 3, "resolution 3 is outside the allowed range 4..256"),
        (TRIANGLE, [[0, 1, 2]], 257, "resolution 257 is outside the allowed range 4..256"),
        (TRIANGLE, [[0, 1, 2]], 8.0, "integer in 4..256"),
    ],
)
def test_bad_input_raises_a_clear_error(vertices, triangles, resolution, words):
    with pytest.raises(VDNIFError, match=words):
        voxels.build_grid(vertices, np.asarray(triangles), resolution)
