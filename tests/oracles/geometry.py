"""The float64 reference geometry the casting and normal kernels are tested against: ray /
triangle crossings (Möller-Trumbore), a brute-force caster over a triangle soup, the trilinear
map of a cell with its Jacobian and the deformed normals J^-T n, and the entry cast and
boundary triangles of a ``kernels.cells.DeviceCells`` as numpy reads them. None of it runs
in the product: the kernels do this work there (``kernels/cast.py``, ``kernels/cells.py``,
``kernels/render.py``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vdnif_addon.geometry.attributes import FALLBACK_NORMAL, SINGULAR_COFACTOR, normalize
from vdnif_addon.geometry.voxels import CORNER_OFFSETS
from vdnif_addon.geometry.walk_rules import BARYCENTRIC_TOLERANCE, CELL_TRIANGLES

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int


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



def _trilinear_factors(local: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N 8 3"]:
    """(N, 8, 3) per-axis linear factors of each corner's weight: u or 1 - u by the corner's
    offset along that axis."""
    local = np.asarray(local, dtype=np.float64)[:, None, :]
    return np.where(CORNER_OFFSETS == 1, local, 1.0 - local)


def trilinear_map(cell_corners: Float[np.ndarray, "N 8 3"], local: Float[np.ndarray, "N 3"]
                  ) -> Float[np.ndarray, "N 3"]:
    """(N, 3) point x(u) = sum_c w_c(u) X_c of cells with corners (N, 8, 3) (corner
    c = dx + 2 dy + 4 dz) at local coordinates u (N, 3) in [0, 1]^3."""
    return np.einsum("nc,nci->ni", _trilinear_factors(local).prod(axis=2), cell_corners)


def trilinear_jacobian(cell_corners: Float[np.ndarray, "N 8 3"],
                       local: Float[np.ndarray, "N 3"]) -> Float[np.ndarray, "N 3 3"]:
    """(N, 3, 3) Jacobian dx/du of ``trilinear_map``; column j is the derivative along u_j."""
    factors = _trilinear_factors(local)
    others = factors[:, :, [[1, 2], [0, 2], [0, 1]]].prod(axis=3)      # (N, 8, 3)
    derivative = np.where(CORNER_OFFSETS == 1, others, -others)         # dw_c / du_j
    return np.einsum("nci,ncj->nij", np.asarray(cell_corners, dtype=np.float64), derivative)


def deformed_normals(rest_normals: Float[np.ndarray, "N 3"],
                     jacobian: Float[np.ndarray, "N 3 3"]) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit normals normalize(J^-T n) of rest normals (N, 3) under Jacobians (N, 3, 3).

    Computed as sign(det J) cof(J) n, with cof(J) = det(J) J^-T built from cross products of
    J's columns: finite for every J, and equal to J^-T n up to a positive factor. J is first
    scaled to unit max entry (a uniform scale leaves the result unchanged), so nothing
    overflows. A singular J counts as det >= 0; where the cofactor normal vanishes (J of rank
    <= 1, or n in its null space) the rest normal is returned.
    """
    rest = normalize(rest_normals, FALLBACK_NORMAL)
    jacobian = np.asarray(jacobian, dtype=np.float64)
    scale = np.abs(jacobian).max(axis=(1, 2), initial=0.0)[:, None, None]
    j = jacobian / np.where(scale > 0, scale, 1.0)
    a, b, c = j[:, :, 0], j[:, :, 1], j[:, :, 2]
    cofactor = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=2)
    sign = np.where((a * cofactor[:, :, 0]).sum(axis=1) < 0, -1.0, 1.0)[:, None]
    deformed = sign * np.einsum("nij,nj->ni", cofactor, rest)
    tiny = np.linalg.norm(deformed, axis=1, keepdims=True) <= SINGULAR_COFACTOR
    return normalize(np.where(tiny, 0.0, deformed), rest)


def entry_cast(cells, origins, directions, max_distance):
    """First hits of rays (N, 3) on the entry BVH of ``cells`` (a DeviceCells) within
    ``max_distance`` (N,), in object units: (index (N,) int64, -1 on a miss; t (N,) inf on a
    miss), as the walk kernel's ``entry_cast`` finds them."""
    frame = (np.asarray(origins, np.float64) - cells.frame_origin) / cells.frame_scale
    index, t = cells.entry.cast(frame, directions,
                                np.asarray(max_distance, np.float64) / cells.frame_scale)
    return index, t * cells.frame_scale


def boundary_triangles(cells):
    """(K, 3, 3) deformed corners of the entry BVH's triangles of ``cells`` (its rows)."""
    local = CELL_TRIANGLES[cells.boundary_triangle]
    return cell_corner_positions(cells)[cells.boundary_cell[:, None], local]


def cell_corner_positions(cells):
    """(N, 8, 3) float64 deformed corners of every cell of ``cells`` in its current pose."""
    return cells.corners[cells.grid.cell_corners]
