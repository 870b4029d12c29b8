"""The deformed-space walk (the Warp kernel) against independent references (no bpy)."""

import numpy as np
import pytest
from oracles import walk as oracle
from oracles.geometry import BruteForceCaster

from vdnif_addon.geometry import voxels
from vdnif_addon.geometry import walk_rules as rules
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.tracing import traverse as tv


@pytest.fixture(scope="module")
def blob():
    """A random closed-ish triangle soup around the unit sphere, voxelized at R=12."""
    rng = np.random.default_rng(7)
    vertices = rng.normal(size=(120, 3))
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    triangles = rng.integers(0, 120, size=(240, 3))
    return voxels.build_grid(vertices, triangles, 12)


def walk(grid, corners, origins, directions, **kw):
    cells = DeviceCells(grid, corners=corners)
    return cells, tv.traverse(cells, origins, directions, **kw)


def slab_intervals(grid, origin, direction):
    """Reference: (t_near, t_far) of every occupied box the ray's line crosses, t_far > 0."""
    lo = grid.origin + grid.cells * grid.voxel_size
    hi = lo + grid.voxel_size
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / direction, (hi - origin) / direction
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    inside = (far > near) & (far > 0)
    return np.maximum(near[inside], 0), far[inside], np.flatnonzero(inside)


def union_length(near, far):
    """Length of the union of intervals (boxes sharing an edge give overlapping ones)."""
    total, reach = 0.0, -np.inf
    for start, stop in sorted(zip(near, far)):
        total += max(0.0, stop - max(start, reach))
        reach = max(reach, stop)
    return total


def random_rays(rng, count, radius=3.0, spread=0.3):
    origins = rng.normal(size=(count, 3))
    origins *= radius / np.linalg.norm(origins, axis=1, keepdims=True)
    directions = rng.normal(size=(count, 3)) * spread - origins
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def test_undeformed_walk_visits_exactly_the_boxes_the_line_crosses(blob):
    rng = np.random.default_rng(1)
    origins, directions = random_rays(rng, 300)
    _, segments = walk(blob, blob.corner_positions(), origins, directions)
    minimum = 1e-4 * blob.voxel_size            # corner grazes shorter than this may be skipped
    for ray in range(len(origins)):
        near, far, cells = slab_intervals(blob, origins[ray], directions[ray])
        mine = segments.ray == ray
        long_enough = far - near > minimum
        assert set(cells[long_enough]) <= set(segments.cell[mine])
        np.testing.assert_allclose(segments.length[mine].sum(), union_length(near, far),
                                   atol=10 * minimum)
    # rest points lie on the ray (the pose is the rest pose) and segments are contiguous
    x0 = origins[segments.ray] + segments.t0[:, None] * directions[segments.ray]
    np.testing.assert_allclose(segments.p0, x0, atol=1e-9)
    assert np.all(segments.length > 0) and np.all(segments.gap >= -1e-9)


def test_segment_rest_points_follow_a_deformation_exactly(blob):
    """Under an affine deformation every rest point maps to its deformed point exactly."""
    linear = np.array([[1.3, 0.2, 0.0], [-0.3, 0.8, 0.1], [0.1, 0.0, 1.1]])
    shift = np.array([0.2, -0.1, 0.3])
    deformed = blob.corner_positions() @ linear.T + shift
    origins, directions = random_rays(np.random.default_rng(2), 200, radius=4.0)
    _, segments = walk(blob, deformed, origins, directions)
    for p, t in ((segments.p0, segments.t0), (segments.p1, segments.t1)):
        x = origins[segments.ray] + t[:, None] * directions[segments.ray]
        np.testing.assert_allclose(p @ linear.T + shift, x, atol=1e-9)
    assert len(segments) > 1000


def test_gap_and_length_accumulate_to_the_exit_distance(blob):
    origins, directions = random_rays(np.random.default_rng(3), 100)
    _, segments = walk(blob, blob.corner_positions(), origins, directions)
    total = np.zeros(len(origins))
    np.add.at(total, segments.ray, segments.gap + segments.length)
    last_exit = np.zeros(len(origins))
    np.maximum.at(last_exit, segments.ray, segments.t1)
    np.testing.assert_allclose(total, last_exit, atol=1e-12)


def axis_grid():
    """A cube voxelized at R=4: a shell of 208 cells around an empty 2x2x2 core, corners on
    integer planes."""
    box = np.array([[x, y, z] for x in (0, 4) for y in (0, 4) for z in (0, 4)], float)
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return voxels.build_grid(box, np.array(faces), 4)


def must_cover(grid, origin, direction, t_max=20.0, spacing=1e-3):
    """Samples (t (S,), needed (S,) bool) along a ray: a point is needed where every cell whose
    closed box holds it is occupied, so the walk must cover it: a surface point there would
    make exactly those cells occupied. Where the ray runs along a face or edge between an
    occupied and an empty cell no surface can lie, and a walk may pass either side."""
    occupied = set(map(tuple, grid.cells.tolist()))
    t = np.arange(0.0, t_max, spacing)
    local = (origin + t[:, None] * direction - grid.origin) / grid.voxel_size
    needed = np.zeros(len(t), bool)
    for row, point in enumerate(local):
        low, high = np.floor(point).astype(int), np.ceil(point).astype(int) - 1
        high = np.maximum(high, low)           # on a plane: the cells on both sides
        low = np.where(point == np.floor(point), low - 1, low)
        boxes = [(i, j, k) for i in range(low[0], high[0] + 1)
                 for j in range(low[1], high[1] + 1) for k in range(low[2], high[2] + 1)]
        needed[row] = all(box in occupied for box in boxes)
    return t, needed


# Rays along a face between occupied and empty cells: which side the walk takes depends on
# which of the boundary triangles meeting there the entry BVH reports first (a tie that a
# float32 BVH, Warp's as Blender's, breaks by its traversal order). The walk must cover every
# needed point; it may skip the rest of the touched boxes.
ALONG_BOUNDARY = ("along a cell edge line", "in a face plane")


@pytest.mark.parametrize("name, origin, direction", [
    ("parallel to x through cell centres", (-3, 0.5, 0.5), (1, 0, 0)),
    ("along a cell edge line", (-3, 1.0, 2.0), (1, 0, 0)),
    ("through grid corners diagonally", (-3, -3, -3), (1, 1, 1)),
    ("across an edge line", (-3, -3, 0.5), (1, 1, 0)),
    ("in a face plane", (-3, 1.0, -2.5), (1, 0, 1)),
    ("grazing the outer face", (-3, -1.0, 0.5), (1, 0, 0)),
    ("missing everything", (-3, 10, 10), (1, 0, 0)),
    ("starting inside", (1.3, 2.2, 0.7), (0.3, -1, 0.2)),
    ("pointing away", (-3, 0.5, 0.5), (-1, 0, 0)),
])
def test_special_rays_terminate_without_nan(name, origin, direction):
    grid = axis_grid()
    origin, direction = np.array([origin], float), np.array([direction], float)
    direction /= np.linalg.norm(direction)
    _, segments = walk(grid, grid.corner_positions(), origin, direction)
    assert segments.truncated == 0
    for array in (segments.t0, segments.t1, segments.p0, segments.p1):
        assert np.isfinite(array).all()
    near, far, _ = slab_intervals(grid, origin[0], direction[0])
    t, needed = must_cover(grid, origin[0], direction[0])
    covered = ((t[:, None] >= segments.t0 - 1e-9) & (t[:, None] <= segments.t1 + 1e-9)).any(1)
    assert not (needed & ~covered).any()
    if name in ALONG_BOUNDARY:
        assert needed.sum() * 1e-3 - 0.01 <= segments.length.sum() <= union_length(near, far)
        assert needed.sum() < 0.9 * union_length(near, far) / 1e-3   # a real choice here
        # the same walk rules (the numpy walk) entering through the lowest-numbered of the
        # tied triangles, as a brute-force caster breaks the tie, cover every touched box
        cells = oracle.DeformedCells(grid, grid.corner_positions())
        brute = oracle.traverse(cells, BruteForceCaster(cells.boundary_triangles()),
                                origin, direction)
        np.testing.assert_allclose(brute.length.sum(), union_length(near, far), atol=1e-6)
    else:
        np.testing.assert_allclose(segments.length.sum(), union_length(near, far), atol=1e-6)
    if name == "starting inside":
        assert segments.t0[0] == 0 and np.allclose(segments.p0[0], origin[0])


def test_inverted_and_collapsed_cells_never_hang_or_produce_nan(blob):
    rng = np.random.default_rng(4)
    deformed = blob.corner_positions().copy()
    deformed[rng.random(len(deformed)) < 0.2] *= -0.5          # folds many cells inside out
    deformed[rng.random(len(deformed)) < 0.05] = 0.0           # collapses some corners
    assert voxels.inverted_cells(deformed, blob.cell_corners).sum() > 10
    origins, directions = random_rays(rng, 200)
    _, segments = walk(blob, deformed, origins, directions, max_steps=4000)
    assert segments.truncated == 0
    assert all(np.isfinite(a).all() for a in (segments.t0, segments.t1, segments.p0,
                                               segments.p1))
    assert np.all(segments.length >= 0)


def test_zero_direction_and_limited_distance():
    grid = axis_grid()
    origins = np.array([[-3, 0.5, 0.5], [-3, 0.5, 0.5]])
    directions = np.array([[0, 0, 0], [1, 0, 0]], float)
    _, segments = walk(grid, grid.corner_positions(), origins, directions,
                       max_distance=np.array([10.0, 5.0]))
    assert set(segments.ray) == {1}
    assert segments.t0.max() <= 5.0 < segments.t1.max()     # the last one crosses it, whole


def test_first_per_ray():
    segments = rules.Segments(ray=np.array([0, 0, 1, 1, 1]), cell=np.zeros(5, int),
                           t0=np.arange(5.0), t1=np.arange(5.0) + 1,
                           p0=np.zeros((5, 3)), p1=np.zeros((5, 3)))
    mask = np.array([False, True, False, True, True])
    np.testing.assert_array_equal(segments.first_per_ray(mask, 3), [1, 3, -1])


def test_face_triangles_cover_each_face_and_point_outward():
    rest = voxels.CORNER_OFFSETS.astype(float)
    for face in range(6):
        tri = rest[rules.FACE_TRIANGLES[face]]                       # (2, 3, 3)
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        outward = np.zeros(3)
        outward[rules.FACE_AXIS[face]] = 1 if rules.FACE_SIDE[face] else -1
        assert np.allclose(normal, outward[None])     # |normal| = 2 x area 1/2, outward
        corners = set(rules.FACE_TRIANGLES[face].ravel())
        assert len(corners) == 4 and all(rest[c][rules.FACE_AXIS[face]] ==
                                         rules.FACE_SIDE[face] for c in corners)
    # a shared face is split along the same diagonal from both cells (watertight)
    for minus, plus in ((0, 1), (2, 3), (4, 5)):
        axis = rules.FACE_AXIS[minus]
        from_plus = rest[rules.FACE_TRIANGLES[plus]].copy()
        from_minus = rest[rules.FACE_TRIANGLES[minus]].copy()
        from_minus[..., axis] += 1                               # the neighbour's -face
        assert {frozenset(map(tuple, t)) for t in from_plus} == \
            {frozenset(map(tuple, t)) for t in from_minus}


@pytest.mark.parametrize("lanes", [2, 3])
def test_a_walk_in_lanes_gives_one_lanes_segments(blob, lanes):
    """A walk in lanes walks them at once, each on a thread of its own with a buffer of its
    own (also one that fills and grows): the Segments, sorted by ray, equal one lane's bit
    for bit, run after run."""
    from vdnif_addon.kernels.walk import walk_segments

    bend = np.array([[1.1, 0.3, 0.0], [-0.2, 0.9, 0.1], [0.0, 0.1, 1.2]])
    cells = DeviceCells(blob, corners=blob.corner_positions() @ bend.T)
    origins, directions = random_rays(np.random.default_rng(11), 3000, radius=4.0)
    one = tv.traverse(cells, origins, directions, lanes=1)
    assert len(one) > 3000
    for capacity in (None, 256):
        for _ in range(3):
            many = walk_segments(cells, origins, directions, capacity=capacity, lanes=lanes)
            for name in ("ray", "cell", "t0", "t1", "p0", "p1"):
                np.testing.assert_array_equal(getattr(many, name), getattr(one, name), name)
            assert many.truncated == one.truncated
