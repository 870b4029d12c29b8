"""What every walk through voxel cells shares (DESIGN sections 5 and 6): the face tables, the
walk's tolerance and limits, and ``Segments``, the per-voxel pieces of rays every walk
returns.

Each face is split into two triangles along the diagonal from its lowest to its highest
lattice corner, so a face shared by two cells is split identically and the cell complex is
watertight. The deformed walk (``kernels/walk.py``, ``kernels/cells.py``), the static DDA
(``kernels/dda.py``), the reference geometry (``traverse.py``) and the test oracles read
these from here; this module imports nothing of the package.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

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
