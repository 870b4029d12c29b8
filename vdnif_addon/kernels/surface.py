"""First surface hits of rays and rest-space segments, with what the ground truth reads at
the hit, in one kernel per query (DESIGN sections 6 and 9).

A ``SurfaceCaster`` is a triangle mesh with per-corner shading normals: its triangles in a
Warp BVH, each triangle's corners in float64 beside it. One launch casts every ray (or
segment) against the BVH in float32, then, on the hit triangle in float64, refines the
distance to the triangle's plane and takes the barycentric weights of the hit point and the
interpolated shading normal. Albedo and material stay with the caller: they are table reads
or texture lookups, vectorized over hits only (``attributes.surface_albedo``).

Segments of the walk each lie in one voxel cell, so a caster given the cells' boxes keeps,
for every cell, the triangles that can meet a segment there, as one BVH subtree per cell
(Warp's grouped mesh: a triangle appears once per cell it meets); a segment is then cast
in its cell's subtree only. Measured on the walked segments of the arm (6.5 triangles per
cell) and the bunny (35) at R = 32: 2.1x and 1.6x less cast time than from the root of the
whole mesh's BVH, with the same hits.

The rest mesh is one static caster per capture; the deformed mesh of the true reference is one
caster per posed object, ``refit`` to each pose's vertices and normals (same triangles).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import warp as wp

from ..errors import VDNIFError
from ..geometry.attributes import DEGENERATE_SIN2, FALLBACK_NORMAL
from . import runtime

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    Hits = tuple[Int[np.ndarray, " N"], Float[np.ndarray, " N"], Float[np.ndarray, "N 3"],
                 Float[np.ndarray, "N 3"]]
    """Triangle (-1 on a miss), distance, barycentric weights and unit shading normal of N
    casts (zeros on a miss)."""

# A float32 BVH distance is replaced by the float64 distance to the hit triangle's plane when
# the two agree within this relative tolerance (always, but for rays grazing the plane, where
# the plane distance is ill-conditioned and the BVH's answer is kept).
REFINE_TOLERANCE = 1e-3

_DEGENERATE_SIN2 = wp.constant(wp.float64(DEGENERATE_SIN2))
_REFINE_TOLERANCE = wp.constant(wp.float64(REFINE_TOLERANCE))
_FALLBACK_NORMAL = wp.constant(wp.vec3d(*FALLBACK_NORMAL))


@wp.func
def _edge_weights(point: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """Weights of the nearest point on the longest edge (a degenerate triangle): that edge
    clamped, the first longest of ab, bc, ca on ties; 1/3 each if all corners coincide."""
    ab = wp.length_sq(b - a)
    bc = wp.length_sq(c - b)
    ca = wp.length_sq(a - c)
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    if ab >= bc and ab >= ca:
        if ab == zero:
            third = one / wp.float64(3.0)
            return wp.vec3d(third, third, third)
        s = wp.clamp(wp.dot(point - a, b - a) / ab, zero, one)
        return wp.vec3d(one - s, s, zero)
    if bc >= ca:
        s = wp.clamp(wp.dot(point - b, c - b) / bc, zero, one)
        return wp.vec3d(zero, one - s, s)
    s = wp.clamp(wp.dot(point - c, a - c) / ca, zero, one)
    return wp.vec3d(s, zero, one - s)


@wp.func
def barycentric(point: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """Weights (w_a, w_b, w_c) of ``point`` projected onto the plane of triangle (a, b, c),
    unclamped (negative outside it); a triangle with sin^2 of its angle at ``a`` below
    DEGENERATE_SIN2 has no plane: the nearest point of its longest edge. Finite, sum 1."""
    e1 = b - a
    e2 = c - a
    d = point - a
    d11 = wp.dot(e1, e1)
    d12 = wp.dot(e1, e2)
    d22 = wp.dot(e2, e2)
    denom = d11 * d22 - d12 * d12
    if denom > _DEGENERATE_SIN2 * d11 * d22:
        w1 = (d22 * wp.dot(d, e1) - d12 * wp.dot(d, e2)) / denom
        w2 = (d11 * wp.dot(d, e2) - d12 * wp.dot(d, e1)) / denom
        return wp.vec3d(wp.float64(1.0) - w1 - w2, w1, w2)
    return _edge_weights(point, a, b, c)


@wp.func
def _unit(vector: wp.vec3d, fallback: wp.vec3d):
    """``vector`` normalized, or ``fallback`` where its length is zero or not finite."""
    length = wp.length(vector)
    if length > wp.float64(0.0) and wp.isfinite(length):
        return vector / length
    return fallback


@wp.func
def _surface_hit(
    mesh: wp.uint64,
    root: int,
    item_triangle: wp.array(dtype=wp.int32),
    corners: wp.array(dtype=wp.vec3d),
    corner_normals: wp.array(dtype=wp.vec3),
    origin: wp.vec3d,
    direction: wp.vec3d,
    limit: wp.float64,
):
    """(triangle or -1, distance, weights, unit shading normal) of the first hit within
    ``0 <= t < limit`` (float32) along ``origin + t direction``, searching the BVH from
    ``root``."""
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    far = wp.min(limit, wp.float64(3.0e38))          # float32 range: an infinite limit
    query = wp.mesh_query_ray(mesh, wp.vec3(origin), wp.vec3(direction), wp.float32(far), root)
    if not query.result:
        return int(-1), wp.float64(0.0), zero, zero
    face = item_triangle[query.face]
    base = 3 * face
    a = corners[base]
    b = corners[base + 1]
    c = corners[base + 2]
    e1 = b - a
    e2 = c - a
    t = wp.float64(query.t)
    plane = wp.cross(e1, e2)
    along = wp.dot(plane, direction)
    if (wp.length_sq(plane) > _DEGENERATE_SIN2 * wp.dot(e1, e1) * wp.dot(e2, e2)
            and along != wp.float64(0.0)):
        exact = wp.dot(plane, a - origin) / along
        if wp.abs(exact - t) <= _REFINE_TOLERANCE * (wp.float64(1.0) + wp.abs(t)):
            t = exact
    weights = barycentric(origin + t * direction, a, b, c)
    shading = (weights[0] * wp.vec3d(corner_normals[base])
               + weights[1] * wp.vec3d(corner_normals[base + 1])
               + weights[2] * wp.vec3d(corner_normals[base + 2]))
    normal = _unit(shading, _unit(plane, _FALLBACK_NORMAL))
    return face, t, weights, normal


@wp.kernel(module=WARP_MODULE)
def _ray_hits(
    mesh: wp.uint64,
    item_triangle: wp.array(dtype=wp.int32),
    corners: wp.array(dtype=wp.vec3d),
    corner_normals: wp.array(dtype=wp.vec3),
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    max_distance: wp.array(dtype=wp.float64),
    face: wp.array(dtype=wp.int32),
    distance: wp.array(dtype=wp.float64),
    weights: wp.array(dtype=wp.vec3d),
    normal: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    limit = max_distance[i]
    f = int(-1)
    t = wp.float64(0.0)
    w = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    n = w
    if limit >= wp.float64(0.0):
        f, t, w, n = _surface_hit(mesh, -1, item_triangle, corners, corner_normals,
                                  origins[i], directions[i], limit)
    face[i] = f
    distance[i] = t
    weights[i] = w
    normal[i] = n


@wp.kernel(module=WARP_MODULE)
def _segment_hits(
    mesh: wp.uint64,
    item_triangle: wp.array(dtype=wp.int32),
    corners: wp.array(dtype=wp.vec3d),
    corner_normals: wp.array(dtype=wp.vec3),
    cell_root: wp.array(dtype=wp.int32),
    p0: wp.array(dtype=wp.vec3d),
    p1: wp.array(dtype=wp.vec3d),
    cell: wp.array(dtype=wp.int32),
    margin: wp.float64,
    face: wp.array(dtype=wp.int32),
    distance: wp.array(dtype=wp.float64),
    weights: wp.array(dtype=wp.vec3d),
    normal: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    start = p0[i]
    offset = p1[i] - start
    length = wp.length(offset)
    f = int(-1)
    t = wp.float64(0.0)
    w = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    n = w
    if length > wp.float64(0.0):
        root = int(-1)
        if cell_root.shape[0] > 0:
            root = cell_root[cell[i]]
        direction = offset / length
        f, t, w, n = _surface_hit(mesh, root, item_triangle, corners, corner_normals,
                                  start - margin * direction, direction,
                                  length + wp.float64(2.0) * margin)
        t = wp.clamp(t - margin, wp.float64(0.0), length)
    face[i] = f
    distance[i] = t
    weights[i] = w
    normal[i] = n


@wp.kernel(module=WARP_MODULE)
def _cell_triangles(
    mesh: wp.uint64,
    corners: wp.array(dtype=wp.vec3d),
    lows: wp.array(dtype=wp.vec3d),
    highs: wp.array(dtype=wp.vec3d),
    grow: wp.float64,
    offsets: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    items: wp.array(dtype=wp.int32),
):
    """Triangles that may meet cell ``c``'s box grown by ``grow``: their bounds overlap it
    (the BVH's broad phase) and their plane passes through it (a superset of the exact
    separating-axis test; extra triangles only cost a test). Counts them, and writes them
    from ``offsets[c]`` when ``items`` is not empty."""
    c = wp.tid()
    spread = wp.vec3d(grow, grow, grow)
    low = lows[c] - spread
    high = highs[c] + spread
    centre = (low + high) * wp.float64(0.5)
    half = (high - low) * wp.float64(0.5)
    query = wp.mesh_query_aabb(mesh, wp.vec3(low), wp.vec3(high))
    face = int(0)
    found = int(0)
    while wp.mesh_query_next(query, face):
        a = corners[3 * face]
        plane = wp.cross(corners[3 * face + 1] - a, corners[3 * face + 2] - a)
        if wp.abs(wp.dot(centre - a, plane)) <= wp.dot(half, wp.abs(plane)):
            if items.shape[0] > 0:
                items[offsets[c] + found] = face
            found += 1
    counts[c] = found


@wp.kernel(module=WARP_MODULE)
def _gather_corners(vertices: wp.array(dtype=wp.vec3d), triangles: wp.array(dtype=wp.int32),
                    corners: wp.array(dtype=wp.vec3d)):
    k = wp.tid()
    corners[k] = vertices[triangles[k]]


@wp.kernel(module=WARP_MODULE)
def _group_roots(mesh: wp.uint64, roots: wp.array(dtype=wp.int32)):
    c = wp.tid()
    roots[c] = wp.mesh_get_group_root(mesh, c)


class SurfaceCaster:
    """Triangles ``triangles`` (T, 3) over ``vertices`` (V, 3) with shading normals
    ``corner_normals`` (T, 3, 3) per triangle corner, on Warp ``device``. Hit indices are
    rows of ``triangles``.

    ``cell_boxes`` = (lows (C, 3), highs (C, 3)) are the boxes of the cells that segments lie
    in (``cast_segments``' ``cell`` indexes them), each grown by ``cell_margin`` for the
    triangle lists; without them every segment is cast against the whole mesh. The lists
    belong to the vertices given here: a caster with cells is static (no ``refit``).
    """

    def __init__(self, vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
                 corner_normals: Float[np.ndarray, "T 3 3"], device: str = "cpu",
                 cell_boxes: tuple[Float[np.ndarray, "C 3"], Float[np.ndarray, "C 3"]]
                 | None = None, cell_margin: float = 0.0) -> None:
        runtime.load(WARP_MODULE, device)
        self.device = device
        self._on_cpu = wp.get_device(device).is_cpu
        self.triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
        count = len(self.triangles)
        vertex_count = len(np.asarray(vertices).reshape(-1, 3))
        self.points = wp.empty(vertex_count, dtype=wp.vec3, device=device)
        self.vertices = wp.empty(vertex_count, dtype=wp.vec3d, device=device)
        self.corner_vertex = wp.array(self.triangles.ravel(), dtype=wp.int32, device=device)
        # Each triangle's float64 corners and float32 normals, contiguous: a hit reads two or
        # three cache lines, not one per vertex (it is memory-bound on large meshes).
        self.corners = wp.empty(3 * count, dtype=wp.vec3d, device=device)
        self.corner_normals = wp.empty(3 * count, dtype=wp.vec3, device=device)
        self._set(vertices, corner_normals)
        self.mesh = None
        items = np.arange(count, dtype=np.int32)
        self.cell_root = wp.empty(0, dtype=wp.int32, device=device)
        if count:
            self.mesh = wp.Mesh(points=self.points, indices=self.corner_vertex,
                                bvh_constructor=runtime.BVH_CONSTRUCTOR)
            if cell_boxes is not None:
                items = self._group_by_cell(cell_boxes, cell_margin)
        self.item_triangle = wp.array(items, dtype=wp.int32, device=device)

    def _group_by_cell(self, cell_boxes: tuple[Float[np.ndarray, "C 3"], Float[np.ndarray, "C 3"]],
                       cell_margin: float) -> Int[np.ndarray, " items"]:
        """Rebuilds the BVH with one subtree per cell (a triangle once per cell it may meet)
        and returns the triangle of each BVH item."""
        lows, highs = (wp.array(np.asarray(b, np.float64).reshape(-1, 3), dtype=wp.vec3d,
                                device=self.device) for b in cell_boxes)
        cells = len(lows)
        counts = wp.empty(cells, dtype=wp.int32, device=self.device)
        inputs = [self.mesh.id, self.corners, lows, highs, wp.float64(cell_margin)]
        none = wp.empty(0, dtype=wp.int32, device=self.device)
        wp.launch(_cell_triangles, dim=cells, inputs=[*inputs, none, counts, none],
                  device=self.device)
        count = counts.numpy().astype(np.int64)
        if not count.any():
            return np.arange(len(self.triangles), dtype=np.int32)
        offsets = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int32)
        items = wp.empty(int(count.sum()), dtype=wp.int32, device=self.device)
        wp.launch(_cell_triangles, dim=cells,
                  inputs=[*inputs, wp.array(offsets, device=self.device), counts, items],
                  device=self.device)
        items = items.numpy()
        self.mesh = wp.Mesh(
            points=self.points,
            indices=wp.array(self.triangles[items].ravel(), dtype=wp.int32, device=self.device),
            groups=wp.array(np.repeat(np.arange(cells, dtype=np.int32), count),
                            dtype=wp.int32, device=self.device),
            bvh_constructor=runtime.BVH_CONSTRUCTOR)
        self.cell_root = wp.empty(cells, dtype=wp.int32, device=self.device)
        wp.launch(_group_roots, dim=cells, inputs=[self.mesh.id, self.cell_root],
                  device=self.device)
        return items

    def refit(self, vertices: Float[np.ndarray, "V 3"], corner_normals: Float[np.ndarray, "T 3 3"]
              ) -> None:
        """Moves the vertices (same count and triangles) and replaces the shading normals:
        the same mesh in another pose. The BVH's bounds follow (a refit, no rebuild)."""
        if self.cell_root.shape[0]:
            raise VDNIFError("a surface caster with per-cell triangle lists cannot be refit: "
                             "its lists belong to the vertices it was built on")
        self._set(vertices, corner_normals)
        if self.mesh is not None:
            self.mesh.refit()

    def _set(self, vertices: Float[np.ndarray, "V 3"], corner_normals: Float[np.ndarray, "T 3 3"]
             ) -> None:
        vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
        self.points.assign(vertices.astype(np.float32))
        self.vertices.assign(vertices)
        wp.launch(_gather_corners, dim=len(self.corner_vertex),
                  inputs=[self.vertices, self.corner_vertex, self.corners], device=self.device)
        self.corner_normals.assign(np.asarray(corner_normals, np.float32).reshape(-1, 3))

    def cast_rays(self, origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"],
                  max_distance: float | Float[np.ndarray, " N"]) -> Hits:
        """First hits with ``0 <= t < max_distance`` of rays ``origins`` + t ``directions``
        (N, 3), ``max_distance`` (N,) or scalar (inf: unlimited, < 0: no cast).

        Returns triangle (N,) int64 (-1 on a miss), distance (N,) float64, weights (N, 3)
        float64 and unit shading normal (N, 3) float64; zeros on a miss."""
        count = len(origins)
        limits = np.broadcast_to(np.asarray(max_distance, np.float64), (count,))
        return self._launch(_ray_hits, count, [
            self._vectors(origins), self._vectors(directions),
            wp.array(np.ascontiguousarray(limits), dtype=wp.float64, device=self.device)])

    def cast_segments(self, p0: Float[np.ndarray, "S 3"], p1: Float[np.ndarray, "S 3"],
                      cell: Int[np.ndarray, " S"], margin: float) -> Hits:
        """First hits along the segments ``p0 -> p1`` (S, 3) lying in cells ``cell`` (S,)
        int, each cast from ``margin`` before ``p0`` to ``margin`` after ``p1``; a
        zero-length segment casts nothing.

        Returns as ``cast_rays``, with distance measured from ``p0`` and clamped to the
        segment, [0, |p1 - p0|]."""
        cell = np.asarray(cell)
        cells = self.cell_root.shape[0]
        if cells and len(cell) and (cell.min() < 0 or cell.max() >= cells):
            raise VDNIFError(f"segment cells must index the caster's {cells} cells, got "
                             f"{cell.min()}..{cell.max()}")
        return self._launch(_segment_hits, len(p0), [
            self.cell_root, self._vectors(p0), self._vectors(p1),
            wp.array(cell.astype(np.int32), dtype=wp.int32, device=self.device),
            wp.float64(margin)])

    def _vectors(self, values: Float[np.ndarray, "N 3"]) -> wp.array:
        # On the CPU the kernel reads float64 input in place (a copy costs a tenth of a cast).
        return wp.array(np.ascontiguousarray(values, np.float64).reshape(-1, 3),
                        dtype=wp.vec3d, device=self.device, copy=not self._on_cpu)

    def _launch(self, kernel: wp.Kernel, count: int, inputs: Sequence[Any]) -> Hits:
        if self.mesh is None or count == 0:
            return (np.full(count, -1, np.int64), np.zeros(count), np.zeros((count, 3)),
                    np.zeros((count, 3)))
        face = wp.empty(count, dtype=wp.int32, device=self.device)
        distance = wp.empty(count, dtype=wp.float64, device=self.device)
        weights = wp.empty(count, dtype=wp.vec3d, device=self.device)
        normal = wp.empty(count, dtype=wp.vec3d, device=self.device)
        surface = [self.mesh.id, self.item_triangle, self.corners, self.corner_normals]
        wp.launch(kernel, dim=count, inputs=[*surface, *inputs, face, distance, weights, normal],
                  device=self.device)
        return (face.numpy().astype(np.int64), distance.numpy(), weights.numpy(),
                normal.numpy())
