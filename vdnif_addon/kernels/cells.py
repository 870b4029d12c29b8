"""The occupied cells of a voxel grid on a Warp device, deformed one pose at a time.

DESIGN section 5. ``DeviceCells`` is built once per capture: the corner indices of every
cell, the face-neighbour table, and the boundary triangles (faces whose neighbour is empty,
split along the lowest-highest diagonal) as a ``MeshCaster`` whose points are the grid's
corner array itself, so the entry BVH shares the cells' corners. A pose is then one copy of
the deformed corners, a BVH ``refit`` (same triangles, no rebuild) and one kernel that stores
each cell's 12 face triangles (corner, two edges, |e1| |e2|) for the walk.

The BVH holds the corners in the grid's frame (origin at the grid's corner, the padded grid's
edge as unit): its float32 ray test multiplies three coordinates, which in object units
overflows beyond about 1e12 and underflows below about 1e-12, and in the grid's frame its
rounding is relative to the object, wherever the object sits. ``cast`` gives its hits in
object units, as the walk kernel does.

The walk's float64 geometry lives here as ``wp.func``s: the Möller-Trumbore test, the
refined crossing of a boundary triangle, and the rest-space point of a crossing. Modules that
use them compile with ``fuse_fp`` off, so no multiply-add is fused and the kernels round as
numpy does (the oracle in ``tests/oracles/walk.py`` gives the same bits).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..errors import VDNIFError
from ..geometry.walk_rules import BARYCENTRIC_TOLERANCE, CELL_TRIANGLES, step_budget
from . import runtime
from .cast import MeshCaster

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float

    from ..geometry.voxels import VoxelGrid

TOLERANCE = wp.constant(wp.float64(BARYCENTRIC_TOLERANCE))
ONE_PLUS_TOLERANCE = wp.constant(wp.float64(1.0 + BARYCENTRIC_TOLERANCE))
USABLE_DETERMINANT = wp.constant(wp.float64(1e-12))   # |det| > this * |e1| |e2|, as numpy
TINY_SCALE = wp.constant(wp.float64(1e-300))
REFINE_TOLERANCE = wp.constant(wp.float64(1e-3))     # a float32 hit refined within this
INF = wp.constant(wp.float64(np.inf))
F32_MAX = wp.constant(wp.float64(np.finfo(np.float32).max))


@wp.struct
class Triangle:
    """One face triangle of a deformed cell, as the walk's intersection test wants it."""

    a: wp.vec3d
    e1: wp.vec3d          # b - a
    e2: wp.vec3d          # c - a
    scale: wp.float64     # |e1| |e2|


@wp.struct
class CellArrays:
    """Everything the walk reads about the cells of the current pose."""

    corners: wp.array(dtype=wp.vec3d)            # (C,) deformed corner positions
    rest: wp.array(dtype=wp.vec3d)               # (C,) rest corner positions
    cell_corners: wp.array2d(dtype=wp.int32)     # (N, 8) corner c = dx + 2 dy + 4 dz
    neighbours: wp.array2d(dtype=wp.int32)       # (N, 6) -x,+x,-y,+y,-z,+z; -1 if empty
    local: wp.array2d(dtype=wp.int32)            # (12, 3) CELL_TRIANGLES
    triangles: wp.array(dtype=Triangle)          # (N * 12,) deformed, cell-major
    boundary_cell: wp.array(dtype=wp.int32)      # (K,) cell of entry-BVH triangle k
    boundary_triangle: wp.array(dtype=wp.int32)  # (K,) its triangle in 0..11
    mesh: wp.uint64                              # the entry BVH over the K triangles
    frame_origin: wp.vec3d                       # the BVH's frame: (x - origin) / scale
    frame_scale: wp.float64
    step: wp.float64                             # 1e-6 * max(scene size, cell diagonal)


@wp.func
def dot(x: wp.vec3d, y: wp.vec3d) -> wp.float64:
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


@wp.func
def cross(x: wp.vec3d, y: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2],
                    x[0] * y[1] - x[1] * y[0])


@wp.func
def maximum(a: wp.float64, b: wp.float64) -> wp.float64:
    """numpy's maximum: NaN if either is NaN."""
    if wp.isnan(a) or a >= b:
        return a
    return b


@wp.func
def intersect(o: wp.vec3d, d: wp.vec3d, a: wp.vec3d, e1: wp.vec3d, e2: wp.vec3d,
              scale: wp.float64):
    """Möller-Trumbore, as the oracle ``ray_triangle`` (tests/oracles/geometry.py): (t, u, v,
    hit, outward)."""
    p = cross(d, e2)
    det = dot(e1, p)
    usable = wp.abs(det) > USABLE_DETERMINANT * wp.max(scale, TINY_SCALE)
    inv = wp.float64(0.0)
    if usable:
        inv = wp.float64(1.0) / det
    s = o - a
    u = dot(s, p) * inv
    q = cross(s, e1)
    v = dot(d, q) * inv
    t = dot(e2, q) * inv
    hit = usable and u >= -TOLERANCE and v >= -TOLERANCE and u + v <= ONE_PLUS_TOLERANCE
    return t, u, v, hit, det < wp.float64(0.0)


@wp.func
def boundary_crossing(cells: CellArrays, o: wp.vec3d, d: wp.vec3d, face: wp.int32,
                      t_guess: wp.float64):
    """Where the ray crosses entry-BVH triangle ``face`` that a float32 cast reported at
    ``t_guess``: (t refined in float64 when the exact crossing is close, u, v, whether the
    ray leaves the occupied set there)."""
    cell = cells.boundary_cell[face]
    local = cells.boundary_triangle[face]
    a = cells.corners[cells.cell_corners[cell, cells.local[local, 0]]]
    b = cells.corners[cells.cell_corners[cell, cells.local[local, 1]]]
    c = cells.corners[cells.cell_corners[cell, cells.local[local, 2]]]
    e1 = b - a
    e2 = c - a
    t, u, v, hit, outward = intersect(o, d, a, e1, e2, wp.sqrt(dot(e1, e1) * dot(e2, e2)))
    if not (hit and wp.abs(t - t_guess) < REFINE_TOLERANCE * (wp.float64(1.0)
                                                                + wp.abs(t_guess))):
        t = t_guess
    return t, u, v, outward


@wp.func
def entry_cast(cells: CellArrays, start: wp.vec3d, d: wp.vec3d, limit: wp.float64):
    """The entry BVH's first hit along unit ``d`` from ``start`` within ``limit`` (object
    units): (found, face, t in object units), in the BVH's float32 frame (the oracle's
    ``entry_cast`` in tests/oracles/geometry.py casts the same way)."""
    s = (start - cells.frame_origin) / cells.frame_scale
    query = wp.mesh_query_ray(
        cells.mesh, wp.vec3(wp.float32(s[0]), wp.float32(s[1]), wp.float32(s[2])),
        wp.vec3(wp.float32(d[0]), wp.float32(d[1]), wp.float32(d[2])),
        wp.float32(wp.min(limit / cells.frame_scale, F32_MAX)))
    return query.result, query.face, wp.float64(query.t) * cells.frame_scale


@wp.func
def clip01(x: wp.float64) -> wp.float64:
    if x < wp.float64(0.0):
        return wp.float64(0.0)
    if x > wp.float64(1.0):
        return wp.float64(1.0)
    return x


@wp.func
def rest_point(cells: CellArrays, cell: wp.int32, triangle: wp.int32, u: wp.float64,
               v: wp.float64) -> wp.vec3d:
    """Rest-space point with barycentric (u, v) on a cell's face triangle (DESIGN 6)."""
    a = cells.rest[cells.cell_corners[cell, cells.local[triangle, 0]]]
    b = cells.rest[cells.cell_corners[cell, cells.local[triangle, 1]]]
    c = cells.rest[cells.cell_corners[cell, cells.local[triangle, 2]]]
    u = clip01(u)
    v = clip01(v)
    scale = wp.max(u + v, wp.float64(1.0))
    return a + (b - a) * (u / scale) + (c - a) * (v / scale)


@wp.kernel(module=WARP_MODULE)
def _face_triangles(cells: CellArrays):
    cell, k = wp.tid()
    a = cells.corners[cells.cell_corners[cell, cells.local[k, 0]]]
    b = cells.corners[cells.cell_corners[cell, cells.local[k, 1]]]
    c = cells.corners[cells.cell_corners[cell, cells.local[k, 2]]]
    triangle = Triangle()
    triangle.a = a
    triangle.e1 = b - a
    triangle.e2 = c - a
    triangle.scale = wp.sqrt(dot(triangle.e1, triangle.e1) * dot(triangle.e2, triangle.e2))
    cells.triangles[cell * 12 + k] = triangle


class DeviceCells:
    """The occupied cells of ``grid`` on a Warp device; ``set_pose`` deforms them.

    Boundary triangle k (row k of ``entry``, the entry BVH) is triangle
    ``boundary_triangle[k]`` (0..11, see ``walk_rules.CELL_TRIANGLES``) of cell
    ``boundary_cell[k]``, in the order of ``np.nonzero(grid.neighbours < 0)``.
    """

    def __init__(self, grid: VoxelGrid, device: str = "cpu",
                 corners: Float[np.ndarray, "C 3"] | None = None) -> None:
        """Builds the topology and the entry BVH on ``device``, posed at ``corners`` (C, 3)
        (default: the rest corners)."""
        wp_ = runtime.init()
        runtime.load(WARP_MODULE, device)
        if len(grid.cells) == 0:
            raise VDNIFError("voxel grid has no occupied cells: nothing to traverse")
        self.grid, self.device = grid, device
        self.cell_count = len(grid.cells)
        self.max_steps = step_budget(self.cell_count)
        rest = grid.corner_positions()
        cell, face = np.nonzero(grid.neighbours < 0)
        self.boundary_cell = np.repeat(cell, 2).astype(np.int32)
        self.boundary_triangle = (2 * face[:, None] + np.arange(2)).ravel().astype(np.int32)
        boundary = grid.cell_corners[self.boundary_cell[:, None],
                                     CELL_TRIANGLES[self.boundary_triangle]]      # (K, 3)
        self.frame_origin, self.frame_scale = grid.origin, grid.extent
        self.entry = MeshCaster(self._in_frame(rest), boundary, device)
        # a cell's diagonal, as the oracle measures it (from cell 0's corners 0 and 7)
        self.cell_size = float(np.linalg.norm(rest[grid.cell_corners[0, 7]]
                                              - rest[grid.cell_corners[0, 0]]))
        arrays = CellArrays()
        arrays.corners = wp_.array(rest, dtype=wp_.vec3d, device=device)
        arrays.rest = wp_.array(rest, dtype=wp_.vec3d, device=device)
        arrays.cell_corners = wp_.array(grid.cell_corners, dtype=wp_.int32, device=device)
        arrays.neighbours = wp_.array(grid.neighbours, dtype=wp_.int32, device=device)
        arrays.local = wp_.array(CELL_TRIANGLES.astype(np.int32), dtype=wp_.int32,
                                 device=device)
        arrays.triangles = wp_.empty(12 * self.cell_count, dtype=Triangle, device=device)
        arrays.boundary_cell = wp_.array(self.boundary_cell, dtype=wp_.int32, device=device)
        arrays.boundary_triangle = wp_.array(self.boundary_triangle, dtype=wp_.int32,
                                             device=device)
        arrays.mesh = self.entry.mesh.id if self.entry.mesh is not None else wp_.uint64(0)
        arrays.frame_origin = wp_.vec3d(*self.frame_origin)
        arrays.frame_scale = wp_.float64(self.frame_scale)
        self.arrays = arrays
        self.pose = 0                    # counts set_pose calls: geometry of older poses is gone
        self.set_pose(rest if corners is None else corners)

    def set_pose(self, corners: Float[np.ndarray, "C 3"]) -> DeviceCells:
        """Deforms the cells to ``corners`` (C, 3), the grid's corners in this pose: copies
        them, refits the entry BVH and stores the face triangles. Returns self."""
        corners = np.asarray(corners, np.float64)
        if corners.shape != (len(self.grid.corners), 3):
            raise VDNIFError(f"deformed corners have shape {corners.shape}, the grid has "
                             f"{len(self.grid.corners)} corners")
        self.corners = corners
        self.arrays.corners.assign(corners)
        self.entry.refit(self._in_frame(corners))
        scene_size = float(np.ptp(corners, axis=0).max()) or 1.0
        self.step = 1e-6 * max(scene_size, self.cell_size)
        self.arrays.step = wp.float64(self.step)
        wp.launch(_face_triangles, dim=(self.cell_count, 12), inputs=[self.arrays],
                  device=self.device)
        self.pose += 1
        return self

    def _in_frame(self, points: Float[np.ndarray, "*batch 3"]) -> Float[np.ndarray, "*batch 3"]:
        return (np.asarray(points, np.float64) - self.frame_origin) / self.frame_scale
