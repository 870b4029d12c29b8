"""Traversal in deformed space (DESIGN sections 5 and 6).

A deformed cell is its 8 deformed corners; each face is split into two triangles along the
diagonal from its lowest to its highest lattice corner, so a face shared by two cells is split
identically and the cell complex is watertight. Rays enter the occupied set through its
boundary triangles (found by a BVH over them), then walk from cell to cell through exit
faces. Every crossing point lies on a face triangle; its barycentric coordinates on the same
rest-space triangle give the exact rest-space point, so each walked cell yields a rest-space
segment ``(p0, p1)``.

This module holds what the walk's users share: the face tables, the walk's limits,
``Segments`` and ``traverse``; the walk itself is a Warp kernel (``kernels/walk.py``) over
``kernels.cells.DeviceCells``. ``ray_triangle`` and ``BruteForceCaster`` are the float64
reference geometry that tests check casters against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

    from .kernels.cells import DeviceCells

# Faces in the neighbour-table order -x, +x, -y, +y, -z, +z; corner c = dx + 2 dy + 4 dz.
FACE_AXIS = np.array([0, 0, 1, 1, 2, 2])
FACE_SIDE = np.array([0, 1, 0, 1, 0, 1])
OPPOSITE_FACE = np.array([1, 0, 3, 2, 5, 4])
BARYCENTRIC_TOLERANCE = 1e-7     # inclusive triangle edges: no ray leaks between triangles
ZERO_PASS_LIMIT = 8              # zero-length passes in a row before re-seeking the entry
# Casts one seek may make that each find a face the ray leaves by before the ray is given up
# (truncated). Off inverted cells a ray that left the occupied set next meets a face it
# enters by, or a float32 cast finds the face just left once or twice more; only folded
# cells give longer runs, and a seek that makes no progress (an object so small that
# ``step`` vanishes against its coordinates) would otherwise never end.
SEEK_LIMIT = 64


def step_budget(cells: int) -> int:
    """Cell steps one ray may make through ``cells`` occupied cells: four per cell plus 64,
    a bound that no terminating walk reaches."""
    return 4 * int(cells) + 64


def _face_triangles() -> Int[np.ndarray, "6 2 3"]:
    """(6, 2, 3) corner numbers of each face's two triangles, wound so that the rest-space
    normal points out of the cell, split along the lowest-highest corner diagonal."""
    triangles = np.empty((6, 2, 3), np.int64)
    for face in range(6):
        axis, side = FACE_AXIS[face], FACE_SIDE[face]
        u, v = (axis + 1) % 3, (axis + 2) % 3

        def corner(du: int, dv: int) -> int:
            offset = np.zeros(3, np.int64)
            offset[axis], offset[u], offset[v] = side, du, dv
            return int(offset @ (1, 2, 4))

        a00, a10, a11, a01 = corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)
        pair = [[a00, a10, a11], [a00, a11, a01]]      # normal along +axis
        triangles[face] = pair if side == 1 else [t[::-1] for t in pair]
    return triangles


FACE_TRIANGLES = _face_triangles()
CELL_TRIANGLES = FACE_TRIANGLES.reshape(12, 3)         # triangle k belongs to face k // 2


@dataclass
class Segments:
    """Per-voxel pieces of rays, ordered by ray then by distance along it.

    ``t0``/``t1`` are distances along the (unit-direction) deformed ray at the entry and exit
    of the cell: deformed length ``l = t1 - t0``, gap ``delta = t0 - t1`` of the previous
    segment of the same ray (or ``t0`` for the first one).
    """

    ray: Int[np.ndarray, " S"]        # int64
    cell: Int[np.ndarray, " S"]       # int64 index into grid.cells
    t0: Float[np.ndarray, " S"]       # float64
    t1: Float[np.ndarray, " S"]       # float64
    p0: Float[np.ndarray, "S 3"]     # float64 rest-space entry point
    p1: Float[np.ndarray, "S 3"]     # float64 rest-space exit point
    truncated: int = 0     # rays stopped by the step limit (should stay 0)

    def __len__(self) -> int:
        return len(self.ray)

    @property
    def length(self) -> Float[np.ndarray, " S"]:
        """(S,) l = t1 - t0: deformed length of each segment."""
        return self.t1 - self.t0

    @property
    def gap(self) -> Float[np.ndarray, " S"]:
        """(S,) delta: distance from the previous segment's exit (or the ray origin)."""
        previous_exit = np.zeros_like(self.t0)
        same_ray = np.zeros(len(self.ray), bool)
        same_ray[1:] = self.ray[1:] == self.ray[:-1]
        previous_exit[1:] = np.where(same_ray[1:], self.t1[:-1], 0.0)
        return self.t0 - previous_exit

    def first_per_ray(self, mask: Bool[np.ndarray, " S"], rays: int) -> Int[np.ndarray, " rays"]:
        """(rays,) index of the first segment of each ray where ``mask`` holds, or -1."""
        first = np.full(rays, -1, np.int64)
        hits = np.flatnonzero(mask)[::-1]          # reversed: the earliest write wins last
        first[self.ray[hits]] = hits
        return first


def ray_triangle(origins: Float[np.ndarray, "*batch 3"], directions: Float[np.ndarray, "*batch 3"],
                 a: Float[np.ndarray, "*batch 3"], b: Float[np.ndarray, "*batch 3"],
                 c: Float[np.ndarray, "*batch 3"]
                 ) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"],
                            Float[np.ndarray, "*batch"], Bool[np.ndarray, "*batch"],
                            Bool[np.ndarray, "*batch"]]:
    """Möller-Trumbore for matching (broadcast) rows: origins/directions (..., 3), triangle
    corners (..., 3). Returns (t, u, v, hit, outward): distance, barycentric weights of b and
    c, whether the ray's line crosses the triangle (edges inclusive; parallel rays never
    hit), and whether it crosses along the triangle's normal ``(b - a) x (c - a)``."""
    o, d, a, b, c = (np.moveaxis(x, -1, 0) for x in (origins, directions, a, b, c))
    return _crossings(o, d, a, b - a, c - a)


def _crossings(o: Float[np.ndarray, " 3 *batch"], d: Float[np.ndarray, " 3 *batch"],
               a: Float[np.ndarray, " 3 *batch"], e1: Float[np.ndarray, " 3 *batch"],
               e2: Float[np.ndarray, " 3 *batch"], scale: Float[np.ndarray, "*batch"] | None = None
               ) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"],
                          Float[np.ndarray, "*batch"], Bool[np.ndarray, "*batch"],
                          Bool[np.ndarray, "*batch"]]:
    """Möller-Trumbore on x, y, z components held apart (leading axis of length 3): several
    times faster than ``np.cross`` and ``sum(-1)`` on small trailing axes, which matters
    since the walk lives here. ``scale`` = |e1| |e2| may be given precomputed."""
    p = _cross(d, e2)
    det = _dot(e1, p)
    scale = np.sqrt(_dot(e1, e1) * _dot(e2, e2)) if scale is None else scale
    usable = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    inv = np.where(usable, 1.0 / np.where(usable, det, 1.0), 0.0)
    s = o - a
    u = _dot(s, p) * inv
    q = _cross(s, e1)
    v = _dot(d, q) * inv
    t = _dot(e2, q) * inv
    tol = BARYCENTRIC_TOLERANCE
    hit = usable & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol)
    return t, u, v, hit, det < 0


def _cross(x, y):
    return (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])


def _dot(x, y):
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


class BruteForceCaster:
    """First hit of rays against a triangle soup by testing every triangle: the reference
    caster for tests and the fallback where no BVH is available."""

    def __init__(self, triangles: Float[np.ndarray, "K 3 3"]) -> None:
        """``triangles``: (K, 3, 3) corner positions."""
        self.triangles = np.asarray(triangles, np.float64)

    def cast(self, origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"],
             max_distance: Float[np.ndarray, " N"]
             ) -> tuple[Int[np.ndarray, " N"], Float[np.ndarray, " N"]]:
        """(index (N,) int64, -1 on a miss; t (N,)): first hit with 0 <= t <= max_distance."""
        n = len(origins)
        index, best = np.full(n, -1, np.int64), np.full(n, np.inf)
        a, b, c = (self.triangles[None, :, k] for k in range(3))
        for start in range(0, n, 256):
            rows = slice(start, start + 256)
            t, _, _, hit, _ = ray_triangle(origins[rows, None], directions[rows, None], a, b, c)
            t = np.where(hit & (t >= 0) & (t <= max_distance[rows, None]), t, np.inf)
            index[rows] = np.where(np.isfinite(t.min(1)), t.argmin(1), -1)
            best[rows] = t.min(1)
        return index, np.where(index >= 0, best, np.inf)


def traverse(cells: DeviceCells, origins: Float[np.ndarray, "N 3"],
             directions: Float[np.ndarray, "N 3"],
             max_distance: float | Float[np.ndarray, " N"] | None = None,
             max_steps: int | None = None) -> Segments:
    """Walks rays (N, 3) through ``cells`` (a ``kernels.cells.DeviceCells`` in the pose to
    walk) and returns all their rest-space Segments, ordered by ray then distance.

    ``directions`` are normalized here; ``t`` is measured in the units of ``origins``.
    ``max_distance`` (scalar or (N,)) ends rays; ``max_steps`` bounds each ray's cell steps
    (default ``step_budget``); rays that hit a bound are counted in ``truncated``.
    """
    from .kernels.walk import walk_segments

    return walk_segments(cells, origins, directions, max_distance, max_steps)
