"""Static traversal of the rest grid: the classical LSNIF walk, for comparison.

Without deformation the cells are uniform, so a ray's cells follow from its direction alone
(Amanatides and Woo's DDA): no entry BVH and no face intersections. ``StaticGrid`` walks
every ray through the uniform cells inside the occupied cells' bounds with a Warp kernel
(``kernels/dda.py``, one thread per ray) and records the occupied ones as the same
``walk_rules.Segments`` that ``traverse.traverse`` produces on the undeformed cells: the cost
side-by-side measures the deformation-aware walk against. Never imports bpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import VDNIFError

if TYPE_CHECKING:
    from jaxtyping import Float

    from ..geometry.voxels import VoxelGrid
    from ..geometry.walk_rules import Segments

# Pieces shorter than this fraction of the occupied extent are not recorded: the deformed walk
# skips the same corner and edge grazes (its ``step``), so both give the same cells.
MIN_PIECE = 1e-6


class StaticGrid:
    """The occupied cells of a rest ``voxels.VoxelGrid`` as a dense lookup for the DDA, on a
    Warp ``device``.

    Built once per grid (static preprocessing, not part of a walk's cost).
    """

    def __init__(self, grid: VoxelGrid, device: str = "cpu") -> None:
        import warp as wp

        from ..kernels import dda as kernel
        from ..kernels import runtime

        if len(grid.cells) == 0:
            raise VDNIFError("voxel grid has no occupied cells: nothing to traverse")
        runtime.init()
        cells = grid.cells.astype(np.int64)
        first, last = cells.min(axis=0), cells.max(axis=0)
        self.dims = last - first + 1
        self.voxel_size = grid.voxel_size
        self.low = grid.origin + first * grid.voxel_size       # (3,) bounds of occupied cells
        self.high = self.low + self.dims * grid.voxel_size
        lookup = np.full(tuple(self.dims), -1, np.int32)       # cell index, or -1 if empty
        lookup[tuple((cells - first).T)] = np.arange(len(cells))
        extent = max(float(self.dims.max()), np.sqrt(3.0)) * grid.voxel_size
        self.min_piece = MIN_PIECE * extent
        self.device = device
        arrays = kernel.Grid()
        arrays.lookup = wp.array(lookup.ravel(order="F"), dtype=wp.int32, device=device)
        arrays.dims = wp.vec3i(*(int(n) for n in self.dims))
        arrays.low = wp.vec3d(*self.low)
        arrays.high = wp.vec3d(*self.high)
        arrays.voxel_size = wp.float64(self.voxel_size)
        arrays.min_piece = wp.float64(self.min_piece)
        self.arrays = arrays

    def traverse(self, origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"],
                 max_distance: float | Float[np.ndarray, " N"] | None = None) -> Segments:
        """All rest-space Segments of the rays (N, 3), ordered by ray then distance.

        Same conventions as ``traverse.traverse``: directions are normalized here, rays that
        start inside a cell are cut at their origin (``t0 = 0``), and the piece that crosses
        ``max_distance`` is the ray's last, recorded whole.
        """
        from ..kernels.dda import dda_segments

        origins = np.asarray(origins, np.float64)
        directions = np.asarray(directions, np.float64)
        if origins.shape != directions.shape or origins.ndim != 2 or origins.shape[1] != 3:
            raise VDNIFError(f"rays need origins and directions of shape (N, 3), got "
                             f"{origins.shape} and {directions.shape}")
        norms = np.linalg.norm(directions, axis=1)
        directions = directions / np.where(norms > 0, norms, 1.0)[:, None]
        far = np.full(len(origins), np.inf) if max_distance is None else np.broadcast_to(
            np.asarray(max_distance, np.float64), (len(origins),))
        return dda_segments(self, origins, directions, far, self.device)
