"""Traversal in deformed space (DESIGN sections 5 and 6).

A deformed cell is its 8 deformed corners; each face is split into two triangles along the
diagonal from its lowest to its highest lattice corner, so a face shared by two cells is split
identically and the cell complex is watertight. Rays enter the occupied set through its
boundary triangles (found by a BVH over them), then walk from cell to cell through exit
faces. Every crossing point lies on a face triangle; its barycentric coordinates on the same
rest-space triangle give the exact rest-space point, so each walked cell yields a rest-space
segment ``(p0, p1)``.

This module holds ``traverse``, the walk's entry point; the walk itself is a Warp kernel
(``kernels/walk.py``) over ``kernels.cells.DeviceCells``, and the rules every walk shares
(face tables, limits, ``Segments``) are in ``walk_rules.py``. ``ray_triangle`` and
``BruteForceCaster`` are the float64 reference geometry that tests check casters against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..geometry.walk_rules import BARYCENTRIC_TOLERANCE
from ..kernels.walk import walk_segments

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

    from ..geometry.walk_rules import Segments
    from ..kernels.cells import DeviceCells

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
    return walk_segments(cells, origins, directions, max_distance, max_steps)
