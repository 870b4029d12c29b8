"""The numpy static DDA over the rest grid: the test oracle of the DDA kernel
(``vdnif_addon/kernels/dda.py``), as the product ran it before the kernel replaced it.

Amanatides and Woo's walk through the uniform cells inside the occupied cells' bounds, all
rays at once (one vectorized step per cell boundary crossed), recording the occupied ones.
"""

import numpy as np

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry.walk_rules import Segments
from vdnif_addon.tracing.static_grid import MIN_PIECE


class StaticGrid:
    """The occupied cells of a rest ``voxels.VoxelGrid`` as a dense lookup for the DDA."""

    def __init__(self, grid):
        if len(grid.cells) == 0:
            raise VDNIFError("voxel grid has no occupied cells: nothing to traverse")
        cells = grid.cells.astype(np.int64)
        first, last = cells.min(axis=0), cells.max(axis=0)
        self.dims = last - first + 1
        self.voxel_size = grid.voxel_size
        self.low = grid.origin + first * grid.voxel_size       # (3,) bounds of occupied cells
        self.high = self.low + self.dims * grid.voxel_size
        self.lookup = np.full(tuple(self.dims), -1, np.int64)   # cell index, or -1 if empty
        self.lookup[tuple((cells - first).T)] = np.arange(len(cells))
        extent = max(float(self.dims.max()), np.sqrt(3.0)) * grid.voxel_size
        self.min_piece = MIN_PIECE * extent

    def traverse(self, origins, directions, max_distance=None):
        """All rest-space Segments of the rays (N, 3), ordered by ray then distance.

        Same conventions as ``traverse.traverse``: directions are normalized here, rays that
        start inside a cell are cut at their origin (``t0 = 0``), and the piece that crosses
        ``max_distance`` is the ray's last, recorded whole.
        """
        origins = np.asarray(origins, np.float64)
        directions = np.asarray(directions, np.float64)
        if origins.shape != directions.shape or origins.ndim != 2 or origins.shape[1] != 3:
            raise VDNIFError(f"rays need origins and directions of shape (N, 3), got "
                             f"{origins.shape} and {directions.shape}")
        norms = np.linalg.norm(directions, axis=1)
        directions = directions / np.where(norms > 0, norms, 1.0)[:, None]
        far = np.full(len(origins), np.inf) if max_distance is None else np.broadcast_to(
            np.asarray(max_distance, np.float64), (len(origins),))
        ray, t = self._entry(origins, directions, norms > 0)
        ray, t = ray[t <= far[ray]], t[t <= far[ray]]
        point = origins[ray] + t[:, None] * directions[ray]
        cell = np.clip(np.floor((point - self.low) / self.voxel_size).astype(np.int64), 0,
                       self.dims - 1)
        pieces = []
        while len(ray):
            o, d = origins[ray], directions[ray]
            up = d > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                wall = self.low + (cell + up) * self.voxel_size      # next boundary per axis
                crossing = np.where(d != 0, (wall - o) / d, np.inf)
            axis = crossing.argmin(axis=1)
            rows = np.arange(len(ray))
            t_out = crossing[rows, axis]
            index = self.lookup[cell[:, 0], cell[:, 1], cell[:, 2]]
            within = t_out <= far[ray]
            record = (t <= far[ray]) & (index >= 0) & (t_out - t > self.min_piece)
            pieces.append((ray[record], index[record], t[record], t_out[record]))
            cell[rows, axis] += np.where(up[rows, axis], 1, -1)
            go_on = within & (cell[rows, axis] >= 0) & (cell[rows, axis] < self.dims[axis])
            ray, cell, t = ray[go_on], cell[go_on], np.maximum(t_out, t)[go_on]
        return self._segments(pieces, origins, directions)

    def _entry(self, origins, directions, valid):
        """Rays (M,) that cross the occupied bounds ahead of their origin and the distance
        (M,) where they enter them (0 for rays starting inside)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t_low = (self.low - origins) / directions
            t_high = (self.high - origins) / directions
        inside_slab = (origins >= self.low) & (origins <= self.high)
        parallel = directions == 0                       # the slab is all or nothing
        near = np.where(parallel, np.where(inside_slab, -np.inf, np.inf),
                        np.minimum(t_low, t_high)).max(axis=1)
        far = np.where(parallel, np.where(inside_slab, np.inf, -np.inf),
                       np.maximum(t_low, t_high)).min(axis=1)
        enter = np.maximum(near, 0.0)
        ray = np.flatnonzero(valid & (enter < far))
        return ray, enter[ray]

    @staticmethod
    def _segments(pieces, origins, directions):
        ray, cell, t0, t1 = (np.concatenate(x) for x in zip(*pieces)) if pieces else (
            np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), np.empty(0))
        order = np.argsort(ray, kind="stable")           # pieces come in distance order
        ray, cell, t0, t1 = ray[order], cell[order], t0[order], t1[order]
        o, d = origins[ray], directions[ray]
        return Segments(ray=ray, cell=cell, t0=t0, t1=t1, p0=o + t0[:, None] * d,
                        p1=o + t1[:, None] * d)
