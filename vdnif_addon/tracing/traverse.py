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
(face tables, limits, ``Segments``) are in ``walk_rules.py``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..kernels.walk import walk_segments
from ..threads import walk_lanes

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    from ..geometry.walk_rules import Segments
    from ..kernels.cells import DeviceCells

def traverse(cells: DeviceCells, origins: Float[np.ndarray, "N 3"],
             directions: Float[np.ndarray, "N 3"],
             max_distance: float | Float[np.ndarray, " N"] | None = None,
             max_steps: int | None = None, lanes: int | None = None,
             start_cells: Int[np.ndarray, " N"] | None = None) -> Segments:
    """Walks rays (N, 3) through ``cells`` (a ``kernels.cells.DeviceCells`` in the pose to
    walk) and returns all their rest-space Segments, ordered by ray then distance.

    ``directions`` are normalized here; ``t`` is measured in the units of ``origins``.
    ``max_distance`` (scalar or (N,)) ends rays: the segment that crosses it is a ray's
    last, whole (its ``t1`` lies beyond: compare a hit's distance); ``max_steps`` bounds each
    ray's cell steps (default ``step_budget``); rays that hit a bound are counted in
    ``truncated``. ``lanes`` lanes of rays are walked at once, each on a thread of its own
    (default ``threads.walk_lanes``: one per core on the CPU); the Segments are the same in
    any number. ``start_cells`` (N,) names the cell each ray is thought to start in (-1:
    none): a ray whose origin lies inside that cell or a face neighbour is walked from
    there without the entry casts (DESIGN section 5).
    """
    if lanes is None:
        lanes = walk_lanes(cells.device, len(origins))
    return walk_segments(cells, origins, directions, max_distance, max_steps, lanes=lanes,
                         start_cells=start_cells)
