"""The walk kernel against the numpy walk it replaced (``oracles/walk.py``), both casting on
the same entry BVH (``DeviceCells.cast``), so that both see the same float32 entries and only
the walk logic is compared: same segments (ray, cell, order), end points within 1e-6 voxel,
same truncated count. No bpy."""

import numpy as np
import pytest
from oracles import walk as oracle

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import voxels
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.kernels.segments import segment_buffer, segments_from
from vdnif_addon.kernels.walk import RayWalk, walk_segments
from vdnif_addon.tracing import static_grid as dda
from vdnif_addon.tracing import traverse


@pytest.fixture(scope="module")
def blob():
    """A random triangle soup around the unit sphere at R=12: occupied cells with holes and
    concavities, so rays leave and re-enter the occupied set."""
    rng = np.random.default_rng(7)
    vertices = rng.normal(size=(120, 3))
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    return voxels.build_grid(vertices, rng.integers(0, 120, size=(240, 3)), 12)


def outside_rays(rng, count, radius=3.0, spread=0.3):
    origins = rng.normal(size=(count, 3))
    origins *= radius / np.linalg.norm(origins, axis=1, keepdims=True)
    return origins, rng.normal(size=(count, 3)) * spread - origins


def inside_rays(rng, grid, count):
    origins = grid.origin + rng.random((count, 3)) * grid.dims * grid.voxel_size
    return origins, rng.normal(size=(count, 3))


def lattice_rays(grid):
    """Rays along lattice lines (cell edges), in lattice planes (cell faces), through lattice
    points diagonally, and grazing the grid's outer planes."""
    h, low = grid.voxel_size, grid.origin
    top = low + grid.dims * h
    origins, directions = [], []
    for i in range(1, grid.dims[1]):
        for k in range(1, grid.dims[2], 2):
            origins.append(low + [-2 * h, i * h, k * h])                   # along an edge
            directions.append([1.0, 0.0, 0.0])
            origins.append(low + [-2 * h, i * h, (k + 0.3) * h])           # in a face
            directions.append([1.0, 0.0, 0.7])
    for i in range(grid.dims[0] + 1):
        origins.append(low + [i * h, -2 * h, -2 * h])                     # through corners
        directions.append([0.0, 1.0, 1.0])
        origins.append(low - 2 * h + [i * h, 0.0, 0.0])
        directions.append([1.0, 1.0, 1.0])
    for z in (low[2], top[2]):                                           # grazing outside
        origins.append([low[0] - 2 * h, low[1] + 2.5 * h, z])
        directions.append([1.0, 0.0, 0.0])
    return np.array(origins), np.array(directions)


def assert_same_walk(grid, corners, origins, directions, **kw):
    cells = DeviceCells(grid, corners=corners)
    got = traverse.traverse(cells, origins, directions, **kw)
    expected = oracle.traverse(oracle.DeformedCells(grid, corners), cells, origins,
                               directions, **kw)
    assert got.truncated == expected.truncated
    assert len(got) == len(expected)
    np.testing.assert_array_equal(got.ray, expected.ray)
    np.testing.assert_array_equal(got.cell, expected.cell)
    for name in ("t0", "t1", "p0", "p1"):
        np.testing.assert_allclose(getattr(got, name), getattr(expected, name), rtol=0,
                                   atol=1e-6 * grid.voxel_size)
    return got


def test_rest_pose(blob):
    rng = np.random.default_rng(1)
    got = assert_same_walk(blob, blob.corner_positions(), *outside_rays(rng, 1500))
    assert len(got) > 10000 and got.truncated == 0


def test_affine_pose(blob):
    linear = np.array([[1.3, 0.2, 0.0], [-0.3, 0.8, 0.1], [0.1, 0.0, 1.1]])
    deformed = blob.corner_positions() @ linear.T + [0.2, -0.1, 0.3]
    assert len(assert_same_walk(blob, deformed, *outside_rays(np.random.default_rng(2), 1000,
                                                              radius=4.0))) > 5000


def test_random_deformed_pose(blob):
    rng = np.random.default_rng(3)
    corners = blob.corner_positions()
    deformed = corners + 0.3 * blob.voxel_size * rng.normal(size=corners.shape)
    deformed[:, 0] += 0.2 * corners[:, 2] ** 2                    # and a smooth bend
    origins, directions = outside_rays(rng, 1000)
    assert len(assert_same_walk(blob, deformed, origins, directions)) > 5000


def test_folded_and_inverted_cells(blob):
    rng = np.random.default_rng(4)
    deformed = blob.corner_positions().copy()
    deformed[rng.random(len(deformed)) < 0.2] *= -0.5
    deformed[rng.random(len(deformed)) < 0.05] = 0.0
    assert voxels.inverted_cells(deformed, blob.cell_corners).sum() > 10
    origins, directions = outside_rays(rng, 300)
    assert_same_walk(blob, deformed, origins, directions, max_steps=2000)


def test_rays_along_edges_faces_and_through_corners(blob):
    got = assert_same_walk(blob, blob.corner_positions(), *lattice_rays(blob))
    assert got.truncated == 0 and len(got) > 100


def test_rays_starting_inside(blob):
    rng = np.random.default_rng(5)
    got = assert_same_walk(blob, blob.corner_positions(), *inside_rays(rng, blob, 800))
    assert (got.t0 == 0).sum() > 50                      # many start in an occupied cell
    bent = blob.corner_positions() + 0.2 * blob.voxel_size * rng.normal(
        size=blob.corners.shape)
    assert_same_walk(blob, bent, *inside_rays(rng, blob, 800))


def test_missing_grazing_zero_and_limited_rays(blob):
    rng = np.random.default_rng(6)
    origins, directions = outside_rays(rng, 400)
    directions[:50] = -directions[:50]                   # pointing away: no segment
    directions[50:60] = 0.0                              # no direction: no segment
    limits = rng.uniform(1.5, 4.0, 400)                  # rays ending inside the object
    got = assert_same_walk(blob, blob.corner_positions(), origins, directions,
                           max_distance=limits)
    assert not np.isin(got.ray, np.arange(60)).any()
    assert (got.t0 <= limits[got.ray]).all()            # the last one may cross its limit
    crossing = got.t1 > limits[got.ray]
    assert crossing.sum() > 100
    last = np.r_[got.ray[1:] != got.ray[:-1], True]
    assert not (crossing & ~last).any()


def test_step_limit_truncates_the_same_rays(blob):
    origins, directions = outside_rays(np.random.default_rng(7), 300)
    got = assert_same_walk(blob, blob.corner_positions(), origins, directions, max_steps=6)
    assert got.truncated > 20


@pytest.mark.parametrize("scale", [1e-15, 1e15])
def test_extreme_object_scales_walk_like_scale_one(blob, scale):
    """The entry BVH lives in the grid's frame, so tiny and huge objects walk the cells of
    the unit object (at scale 1e-15 a float32 cast in object units never found its way out
    of a face: the seek then looped forever)."""
    rng = np.random.default_rng(8)
    origins, directions = outside_rays(rng, 300)
    unit = traverse.traverse(DeviceCells(blob), origins, directions)
    grid = voxels.VoxelGrid(origin=blob.origin * scale, voxel_size=blob.voxel_size * scale,
                            dims=blob.dims, resolution=blob.resolution, cells=blob.cells,
                            neighbours=blob.neighbours, corners=blob.corners,
                            cell_corners=blob.cell_corners)
    scaled = assert_same_walk(grid, grid.corner_positions(), origins * scale, directions)
    assert scaled.truncated == 0 and len(scaled) == len(unit)
    np.testing.assert_array_equal(scaled.cell, unit.cell)
    np.testing.assert_allclose(scaled.t0 / scale, unit.t0, rtol=1e-9, atol=1e-12)


def test_a_seek_that_makes_no_progress_is_given_up(blob):
    """With a vanishing ``step`` (an object whose coordinates swallow it) a seek that meets
    the face the ray just left finds it again and again: after SEEK_LIMIT casts the ray is
    given up and counted as truncated, by the kernel as by the oracle (the numpy walk
    before the bound looped forever here)."""
    import warp as wp

    cells = DeviceCells(blob)
    cells.arrays.step = wp.float64(0.0)
    origins, directions = outside_rays(np.random.default_rng(9), 300)
    got = traverse.traverse(cells, origins, directions)
    expected = oracle.traverse(oracle.DeformedCells(blob, blob.corner_positions()), cells,
                               origins, directions, step=0.0)
    assert got.truncated == expected.truncated > 100
    assert len(got) == len(expected) > 1000
    np.testing.assert_array_equal(got.ray, expected.ray)
    np.testing.assert_array_equal(got.cell, expected.cell)


def test_a_full_segment_buffer_resumes_where_it_stopped(blob):
    """Buffers of 7 segments, and waves of 3 segments per ray, give the one-launch walk."""
    rng = np.random.default_rng(10)
    origins, directions = outside_rays(rng, 200)
    bent = blob.corner_positions() + 0.2 * blob.voxel_size * rng.normal(
        size=blob.corners.shape)
    cells = DeviceCells(blob, corners=bent)
    whole = walk_segments(cells, origins, directions)
    small = walk_segments(cells, origins, directions, capacity=7)
    walk, pieces, waves = RayWalk(cells, origins, directions), [], 0
    buffer = segment_buffer(3 * walk.count, cells.device)
    while walk.count:
        buffer.cursor.zero_()
        written = walk.advance(buffer, per_wave=3)
        counts = np.bincount(buffer.ray.numpy()[:written], minlength=200)
        assert counts.max() <= 3
        pieces.append(tuple(getattr(buffer, n).numpy()[:written].copy()
                            for n in ("ray", "cell", "t0", "t1", "p0", "p1")))
        walk.drop_finished()
        waves += 1
    waved = segments_from(pieces, walk.truncated())
    assert len(whole) > 1000 and waves > 3
    for got in (small, waved):
        for name in ("ray", "cell", "t0", "t1", "p0", "p1"):
            np.testing.assert_array_equal(getattr(got, name), getattr(whole, name))


def test_a_full_wave_keeps_its_seek_for_the_drop(blob):
    """A ray whose wave fills as it leaves the occupied set has not cast for its next entry
    yet: it waits, a step past its last segment, for the drop after the network. There a
    ray the network ended (as a hit does) leaves without a cast, and every other one seeks,
    as the one-launch walk would."""
    import warp as wp

    from vdnif_addon.kernels.walk import DONE, SEEK

    origins, directions = outside_rays(np.random.default_rng(14), 1000)
    cells = DeviceCells(blob)
    walk = RayWalk(cells, origins, directions)
    buffer = segment_buffer(walk.count, cells.device)
    written = walk.advance(buffer, per_wave=1)
    mode, t = walk.state.mode.numpy().copy(), walk.state.t.numpy()
    last_t1 = np.full(len(origins), np.nan)
    last_t1[buffer.ray.numpy()[:written]] = buffer.t1.numpy()[:written]
    paused = np.flatnonzero(mode == SEEK)
    assert len(paused) > 20
    np.testing.assert_allclose(t[paused], last_t1[paused] + cells.step, rtol=0, atol=1e-12)
    ended = paused[::2]
    mode[ended] = DONE
    walk.state.mode = wp.array(mode, dtype=wp.int32, device=cells.device)
    left = walk.drop_finished()
    after = walk.state.mode.numpy()
    assert not (after == SEEK).any()
    assert (after[ended] == DONE).all()
    np.testing.assert_array_equal(walk.state.t.numpy()[ended], t[ended])
    assert left == int((after < DONE).sum()) > 0
    assert (after[paused[1::2]] != SEEK).all()


def test_segments_written_in_any_ray_order_come_out_ordered(blob):
    """As a CUDA launch writes them: rays interleaved, each ray's own segments in walk order,
    over two launches. Walk order decides ties in distance (zero-length pieces)."""
    origins, directions = outside_rays(np.random.default_rng(12), 300)
    whole = traverse.traverse(DeviceCells(blob), origins, directions)
    rng = np.random.default_rng(13)
    keys = rng.random(len(whole))[np.searchsorted(np.unique(whole.ray), whole.ray)]
    order = np.argsort(keys, kind="stable")                 # rays shuffled, walks kept
    columns = [getattr(whole, n)[order] for n in ("ray", "cell", "t0", "t1", "p0", "p1")]
    half = len(order) // 2
    pieces = [tuple(c[:half] for c in columns), tuple(c[half:] for c in columns)]
    got = segments_from(pieces, 0)
    assert not np.array_equal(columns[0], whole.ray)
    for name in ("ray", "cell", "t0", "t1", "p0", "p1"):
        np.testing.assert_array_equal(getattr(got, name), getattr(whole, name))


def test_corners_of_another_grid_are_one_line(blob):
    with pytest.raises(VDNIFError, match="corners"):
        DeviceCells(blob).set_pose(np.zeros((5, 3)))


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs CUDA")
def test_cuda_walks_the_same_segments_as_the_cpu(blob):
    """The same kernels on CUDA: same segments once sorted (a CUDA launch writes rays in any
    order), a buffer too small for one launch included. The same rays and cells; distances and
    points within 1e-13 (measured: 4e-15), since the GPU's compiler fuses multiply-adds."""
    rng = np.random.default_rng(11)
    origins, directions = outside_rays(rng, 500)
    bent = blob.corner_positions() + 0.2 * blob.voxel_size * rng.normal(
        size=blob.corners.shape)
    cpu = traverse.traverse(DeviceCells(blob, corners=bent), origins, directions)
    cells = DeviceCells(blob, "cuda:0", corners=bent)
    for got in (traverse.traverse(cells, origins, directions),
                walk_segments(cells, origins, directions, capacity=100)):
        assert got.truncated == cpu.truncated and len(got) == len(cpu) > 1000
        for name in ("ray", "cell"):
            np.testing.assert_array_equal(getattr(got, name), getattr(cpu, name))
        for name in ("t0", "t1", "p0", "p1"):
            np.testing.assert_allclose(getattr(got, name), getattr(cpu, name), rtol=1e-13,
                                       atol=1e-13)


def grid_of(cells, dims):
    """A unit grid at the origin whose occupied cells are ``cells`` (M, 3) ijk."""
    dims = np.asarray(dims, np.int64)
    linear = np.sort(np.ravel_multi_index(np.asarray(cells).T, tuple(dims), order="F"))
    ijk = voxels._unravel(linear, dims)
    corners, cell_corners = voxels._corner_lattice(ijk, dims)
    return voxels.VoxelGrid(origin=np.zeros(3), voxel_size=1.0, dims=dims,
                            resolution=int(dims.max()) - 2, cells=ijk.astype(np.int32),
                            neighbours=voxels._neighbour_table(ijk, linear, dims),
                            corners=corners, cell_corners=cell_corners)


def test_a_cell_across_an_edge_or_corner_within_step_is_walked():
    """Cells that touch only along an edge (0,0,0)-(1,1,0), or at a corner (0,0,0)-(1,1,1):
    a ray passing the edge or corner at a distance ``a`` crosses an empty cell for about
    ``a``. The re-seek after the first cell starts ``step`` (2e-6 here) beyond its exit, so
    for a gap shorter than that it starts inside the second cell; the walk used to pass that
    cell's far face and drop the cell (the bunny at R=32 lost 1 to 6 segments per 256x256
    view so). The static DDA walks the same cells: both cells for every ray."""
    offsets = np.array([0.0, 1e-9, 1e-7, 5e-7, 1.3e-6, 3e-6, 1e-4])
    origins, directions = [], []
    for a in offsets:
        for sign in (1.0, -1.0):                 # past either side of the edge
            d = np.array([1.0, 1.0, 0.1])        # crosses x = 1 at y = 1 - sign a, z = 0.5
            origins.append(np.array([1.0, 1.0 - sign * a, 0.5]) - 1.5 * d)
            directions.append(d)
    edge_rays = len(origins)
    for a in offsets:
        d = np.array([1.0, 1.1, 1.2])            # crosses x = 1 near the corner (1, 1, 1)
        origins.append(np.array([1.0, 1.0 - a, 1.0 - 2 * a]) - 0.8 * d)
        directions.append(d)
    origins, directions = np.array(origins), np.array(directions)
    for grid, rays in ((grid_of([[0, 0, 0], [1, 1, 0]], (2, 2, 1)), slice(0, edge_rays)),
                       (grid_of([[0, 0, 0], [1, 1, 1]], (2, 2, 2)), slice(edge_rays, None))):
        got = assert_same_walk(grid, grid.corner_positions(), origins[rays], directions[rays])
        static = dda.StaticGrid(grid).traverse(origins[rays], directions[rays])
        assert got.truncated == 0
        np.testing.assert_array_equal(got.ray, static.ray)
        np.testing.assert_array_equal(got.cell, static.cell)
        np.testing.assert_array_equal(np.bincount(got.ray), 2)


def test_a_lost_walker_re_seeks_whatever_its_max_distance():
    """A walker that crosses no face of its cell (a lost walker: the cell is folded back
    behind the face it was entered by) re-seeks past the cell, and the ray's max distance
    only cuts what lies beyond it. Cells A, B and C along y, an empty cell between B and C;
    B's far corners folded to before its entry face, the -x ones tilted so that the plane of
    B's triangle 0 meets the ray beyond the limit (the walk used to compare that crossing,
    an argmax over no candidate, with the limit and end the ray in B, dropping C)."""
    grid = grid_of([[1, 1, 1], [1, 2, 1], [1, 4, 1]], (3, 6, 3))       # cells A, B, C
    corners = grid.corner_positions()
    folded = corners[:, 1] == 3.0                                     # B's +y corners
    corners[folded, 1] = 1.5
    corners[folded & (corners[:, 0] == 1.0), 0] = 0.95
    origins, directions = np.array([[1.5, -1.0, 1.5]]), np.array([[0.0, 1.0, 0.0]])
    whole = assert_same_walk(grid, corners, origins, directions)
    cut = assert_same_walk(grid, corners, origins, directions, max_distance=7.0)
    for got in (whole, cut):
        np.testing.assert_array_equal(got.cell, [0, 2])        # B lost (no segment), C reached
        np.testing.assert_allclose(np.c_[got.t0, got.t1], [[2.0, 3.0], [5.0, 6.0]])
        assert got.truncated == 0


def test_a_ray_starting_inside_walks_to_its_max_distance():
    """Six cells in a row along x (a unit grid); rays start inside the first one and the
    set's boundary ahead (x = 7) lies beyond their limit. Each walks its cells up to the
    limit, the one that crosses it whole, at rest and bent (the walk used to cast for the
    set's boundary only within the limit, found none and lost the ray). A ray from outside
    whose entry lies beyond its limit still walks nothing."""
    grid = grid_of([[i, 1, 1] for i in range(1, 7)], (8, 3, 3))
    origins = np.array([[1.5, 1.5, 1.5], [1.5, 1.4, 1.6], [1.5, 1.5, 1.5], [-3.0, 1.5, 1.5]])
    directions = np.tile([1.0, 0.0, 0.0], (4, 1))
    limits = np.array([2.2, 0.3, np.inf, 3.9])
    got = assert_same_walk(grid, grid.corner_positions(), origins, directions,
                           max_distance=limits)
    np.testing.assert_array_equal(got.ray, [0, 0, 0, 1, 2, 2, 2, 2, 2, 2])
    np.testing.assert_array_equal(got.cell, [0, 1, 2, 0, 0, 1, 2, 3, 4, 5])
    np.testing.assert_allclose(got.t0, [0, 0.5, 1.5, 0, 0, 0.5, 1.5, 2.5, 3.5, 4.5], atol=1e-12)
    np.testing.assert_allclose(got.t1, [0.5, 1.5, 2.5, 0.5, 0.5, 1.5, 2.5, 3.5, 4.5, 5.5],
                               atol=1e-12)
    np.testing.assert_allclose(got.p0, origins[got.ray] + got.t0[:, None] * [1, 0, 0],
                               atol=1e-12)
    assert got.truncated == 0
    bent = grid.corner_positions()
    bent[:, 1] += 0.1 * bent[:, 0]                      # a shear: the row tilts up in y
    along = np.array([[1.0, 0.1, 0.0]])
    sheared = assert_same_walk(grid, bent, np.array([[1.5, 1.65, 1.5]]), along,
                               max_distance=1.6 * np.linalg.norm(along))
    np.testing.assert_array_equal(sheared.cell, [0, 1, 2])
    np.testing.assert_allclose(sheared.p0[0], [1.5, 1.5, 1.5], atol=1e-12)


def test_a_limited_walk_is_the_unlimited_walk_up_to_its_limit(blob):
    """Rays from inside and outside the occupied set with random limits: their segments are
    those of the unlimited walk that begin within the limit, the last one whole."""
    rng = np.random.default_rng(14)
    bent = blob.corner_positions() + 0.2 * blob.voxel_size * rng.normal(
        size=blob.corners.shape)
    inside = inside_rays(rng, blob, 400)
    outside = outside_rays(rng, 400)
    origins, directions = (np.concatenate(pair) for pair in zip(inside, outside))
    limits = rng.uniform(0.0, 4.0, len(origins))
    whole = assert_same_walk(blob, bent, origins, directions)
    cut = assert_same_walk(blob, bent, origins, directions, max_distance=limits)
    keep = whole.t0 <= limits[whole.ray]
    assert 2000 < keep.sum() < len(whole) - 2000
    assert (cut.t1 > limits[cut.ray]).sum() > 150       # the segments crossing a limit
    assert len(np.unique(cut.ray[cut.ray < 400])) > 150  # rays from inside walk
    for name in ("ray", "cell", "t0", "t1", "p0", "p1"):
        np.testing.assert_array_equal(getattr(cut, name), getattr(whole, name)[keep])


def start_cells_of(segments, count):
    """The cell each ray's walk holds its origin in (its segment cut at the origin), -1 for a
    ray that starts outside the occupied cells."""
    start = np.full(count, -1)
    first = np.flatnonzero(segments.t0 == 0)
    start[segments.ray[first]] = segments.cell[first]
    return start


def test_rays_given_their_start_cells_walk_as_without_them(blob):
    """Rays from random points, at rest and bent, limited and not, given as start cells
    their own, a face neighbour of their own (whose inside does not hold the origin: its
    neighbours are tried), a cell far away and none: the segments of the walk without start
    cells (the same rays and cells in order, end points within 1e-6 voxel)."""
    rng = np.random.default_rng(11)
    bent = blob.corner_positions() + 0.2 * blob.voxel_size * rng.normal(
        size=blob.corners.shape)
    for corners in (blob.corner_positions(), bent):
        cells = DeviceCells(blob, corners=corners)
        origins, directions = inside_rays(rng, blob, 800)
        limits = np.where(rng.random(800) < 0.5, np.inf,
                          rng.uniform(0.3, 3.0, 800) * blob.voxel_size)
        plain = traverse.traverse(cells, origins, directions, max_distance=limits)
        own = start_cells_of(plain, len(origins))
        inside = own >= 0
        assert inside.sum() > 50
        neighbours = blob.neighbours[np.maximum(own, 0)]
        pick = np.argmax(neighbours >= 0, axis=1)
        neighbour = np.where(inside & (neighbours.max(1) >= 0),
                             neighbours[np.arange(len(own)), pick], own)
        assert (neighbour != own).sum() > 50
        far = np.where(inside, (own + len(blob.cells) // 2) % len(blob.cells), 0)
        for hints in (own, neighbour, far, np.full(len(origins), -1)):
            got = traverse.traverse(cells, origins, directions, max_distance=limits,
                                    start_cells=hints)
            assert got.truncated == plain.truncated
            np.testing.assert_array_equal(got.ray, plain.ray)
            np.testing.assert_array_equal(got.cell, plain.cell)
            for name in ("t0", "t1", "p0", "p1"):
                np.testing.assert_allclose(getattr(got, name), getattr(plain, name), rtol=0,
                                           atol=1e-6 * blob.voxel_size)


def test_a_start_cell_spares_the_walk_behind_the_origin():
    """Six cells in a row along x; a ray starts in the fifth. Without a start cell it is
    walked from the row's entry, four cells behind its origin, and a budget of two cell
    steps truncates it before its origin; given its cell, or the cell behind it, it starts
    there and walks its two cells within that budget. A start cell whose inside and whose
    neighbours' do not hold the origin is not taken."""
    grid = grid_of([[i, 1, 1] for i in range(1, 7)], (8, 3, 3))
    cells = DeviceCells(grid)
    origins, directions = np.array([[5.5, 1.5, 1.5]]), np.array([[1.0, 0.0, 0.0]])
    whole = traverse.traverse(cells, origins, directions)
    np.testing.assert_array_equal(whole.cell, [4, 5])
    for start in (-1, 0):
        cut = traverse.traverse(cells, origins, directions, max_steps=2,
                                start_cells=np.array([start]))
        assert len(cut) == 0 and cut.truncated == 1
    for start in (4, 3):
        got = traverse.traverse(cells, origins, directions, max_steps=2,
                                start_cells=np.array([start]))
        assert got.truncated == 0
        np.testing.assert_array_equal(got.cell, [4, 5])
        np.testing.assert_allclose(np.c_[got.t0, got.t1], [[0.0, 0.5], [0.5, 1.5]],
                                   atol=1e-12)
        np.testing.assert_allclose(got.p0, [[5.5, 1.5, 1.5], [6.0, 1.5, 1.5]], atol=1e-12)


@pytest.mark.parametrize("start_cells", [[0], [0, 1, 2], [-2, 0], [0, 6], [0.0, 1.0]])
def test_start_cells_that_are_not_one_cell_per_ray_are_one_line(start_cells):
    grid = grid_of([[i, 1, 1] for i in range(1, 7)], (8, 3, 3))
    with pytest.raises(VDNIFError, match="start cells need one integer in -1..5 per ray"):
        traverse.traverse(DeviceCells(grid), np.zeros((2, 3)), np.ones((2, 3)),
                          start_cells=np.array(start_cells))
