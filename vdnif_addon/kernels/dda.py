"""The static DDA over the rest grid as one Warp kernel: one thread per ray.

Amanatides and Woo's walk through the uniform cells inside the occupied cells' bounds (no
entry BVH, no face intersections), recording the occupied cells as segments through the same
buffers (``kernels/segments.py``) and with the same per-ray state, launches and collection as
the deformed walk (``kernels/walk.py``), so the two compare like with like. The numbers are
the numpy DDA's that this kernel replaced (``tests/oracles/dda.py``): crossing distances
``(wall - o) / d``, recomputed only on the axis that stepped, and end points ``o + t d``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
import warp as wp

from . import runtime
from .segments import SegmentBuffer, collect, emit, reusable_buffer, segment_buffer, segments_from

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float

    from ..geometry.walk_rules import Segments

ENTER = wp.constant(0)
WALK = wp.constant(2)
DONE = wp.constant(3)
INF = wp.constant(wp.float64(np.inf))


@wp.struct
class Grid:
    lookup: wp.array(dtype=wp.int32)    # dense cell index (i + dims0 (j + dims1 k)), -1 empty
    dims: wp.vec3i
    low: wp.vec3d                        # bounds of the occupied cells
    high: wp.vec3d
    voxel_size: wp.float64
    min_piece: wp.float64               # shorter pieces are not recorded


@wp.struct
class DDAState:
    origin: wp.array(dtype=wp.vec3d)
    direction: wp.array(dtype=wp.vec3d)   # unit, zero for a zero direction
    far: wp.array(dtype=wp.float64)
    mode: wp.array(dtype=wp.int32)
    t: wp.array(dtype=wp.float64)
    cell: wp.array(dtype=wp.vec3i)


@wp.func
def wall_crossing(low: wp.float64, h: wp.float64, o: wp.float64, d: wp.float64,
                  cell: wp.int32) -> wp.float64:
    """Distance along one axis to the cell's next wall (inf for a ray parallel to it)."""
    if d == wp.float64(0.0):
        return INF
    up = wp.int32(0)
    if d > wp.float64(0.0):
        up = 1
    return (low + wp.float64(cell + up) * h - o) / d


@wp.func
def grid_entry(grid: Grid, o: wp.vec3d, d: wp.vec3d, far: wp.float64):
    """Where the ray enters the occupied cells' bounds (slab test): (whether it does within
    ``far``, the entry distance, the cell there)."""
    h = grid.voxel_size
    near = -INF
    leave = INF
    valid = d[0] != wp.float64(0.0) or d[1] != wp.float64(0.0) or d[2] != wp.float64(0.0)
    for axis in range(3):
        if d[axis] == wp.float64(0.0):
            if not (o[axis] >= grid.low[axis] and o[axis] <= grid.high[axis]):
                valid = False           # parallel to a slab it is not in
        else:
            t_low = (grid.low[axis] - o[axis]) / d[axis]
            t_high = (grid.high[axis] - o[axis]) / d[axis]
            near = wp.max(near, wp.min(t_low, t_high))
            leave = wp.min(leave, wp.max(t_low, t_high))
    t = wp.max(near, wp.float64(0.0))
    cell = wp.vec3i(0, 0, 0)
    entered = valid and t < leave and t <= far
    if entered:
        point = o + d * t
        for axis in range(3):
            index = wp.int32(wp.floor((point[axis] - grid.low[axis]) / h))
            cell[axis] = wp.clamp(index, 0, grid.dims[axis] - 1)
    return entered, t, cell


@wp.func
def first_wall(tx: wp.float64, ty: wp.float64, tz: wp.float64):
    """The nearest of the three next walls: (its distance, its axis); ties go to the lowest
    axis."""
    t_out = tz
    axis = wp.int32(2)
    if ty <= tz:
        t_out = ty
        axis = wp.int32(1)
    if tx <= t_out:
        t_out = tx
        axis = wp.int32(0)
    return t_out, axis


@wp.func
def step_index(i: wp.int32, d: wp.float64, count: wp.int32):
    """The cell index past the wall the ray crosses along one axis: (index, whether it is
    still inside the grid's ``count`` cells)."""
    if d > wp.float64(0.0):
        i += 1
    else:
        i -= 1
    return i, i >= 0 and i < count


@wp.kernel(module=WARP_MODULE)
def dda_rays(grid: Grid, rays: DDAState, active: wp.array(dtype=wp.int32),
             out: SegmentBuffer):
    r = active[wp.tid()]
    mode = rays.mode[r]
    if mode == DONE:
        return
    o = rays.origin[r]
    d = rays.direction[r]
    far = rays.far[r]
    t = rays.t[r]
    cell = rays.cell[r]
    h = grid.voxel_size
    if mode == ENTER:
        entered, t, cell = grid_entry(grid, o, d, far)
        if not entered:
            rays.mode[r] = DONE
            return
        mode = WALK
    # the walk in scalars: a vector indexed by a run-time axis would live in memory
    i = cell[0]
    j = cell[1]
    k = cell[2]
    tx = wall_crossing(grid.low[0], h, o[0], d[0], i)
    ty = wall_crossing(grid.low[1], h, o[1], d[1], j)
    tz = wall_crossing(grid.low[2], h, o[2], d[2], k)
    while mode == WALK:
        if out.cursor[0] >= out.capacity:
            break                                          # paused until the next launch
        t_out, axis = first_wall(tx, ty, tz)
        index = grid.lookup[i + grid.dims[0] * (j + grid.dims[1] * k)]
        within = t_out <= far
        if t <= far and index >= 0 and t_out - t > grid.min_piece:   # the last one whole
            if emit(out, r, index, t, t_out, o + d * t, o + d * t_out) < 0:
                break                                      # buffer full: redo this step later
        inside = False
        if axis == 0:
            i, inside = step_index(i, d[0], grid.dims[0])
            tx = wall_crossing(grid.low[0], h, o[0], d[0], i)
        elif axis == 1:
            j, inside = step_index(j, d[1], grid.dims[1])
            ty = wall_crossing(grid.low[1], h, o[1], d[1], j)
        else:
            k, inside = step_index(k, d[2], grid.dims[2])
            tz = wall_crossing(grid.low[2], h, o[2], d[2], k)
        if not (within and inside):
            mode = DONE
        t = wp.max(t_out, t)
    rays.mode[r] = mode
    rays.t[r] = t
    rays.cell[r] = wp.vec3i(i, j, k)


@wp.kernel(module=WARP_MODULE)
def _still_walking(rays: DDAState, active: wp.array(dtype=wp.int32),
                   keep: wp.array(dtype=wp.int32), cursor: wp.array(dtype=wp.int32)):
    r = active[wp.tid()]
    if rays.mode[r] != DONE:
        keep[wp.atomic_add(cursor, 0, 1)] = r


class GridOwner(Protocol):
    """What the walk needs of a static grid (``tracing.static_grid.StaticGrid``): its device
    arrays; it also keeps the walk's segment buffer between calls."""

    arrays: Grid


def dda_segments(static_grid: GridOwner, origins: Float[np.ndarray, "N 3"],
                 directions: Float[np.ndarray, "N 3"], far: Float[np.ndarray, " N"], device: str,
                 capacity: int | None = None) -> Segments:
    """Segments of rays (N, 3) with unit (or zero) ``directions`` and limits ``far`` (N,)
    through a static grid (its ``arrays`` on ``device``)."""
    runtime.load(WARP_MODULE, device)
    count = len(origins)
    state = DDAState()
    state.origin = wp.array(origins, dtype=wp.vec3d, device=device)
    state.direction = wp.array(directions, dtype=wp.vec3d, device=device)
    state.far = wp.array(far, dtype=wp.float64, device=device)
    state.mode = wp.zeros(count, dtype=wp.int32, device=device)
    state.t = wp.zeros(count, dtype=wp.float64, device=device)
    state.cell = wp.zeros(count, dtype=wp.vec3i, device=device)
    active = wp.array(np.arange(count, dtype=np.int32), dtype=wp.int32, device=device)
    spare = wp.empty(count, dtype=wp.int32, device=device)
    cursor = wp.zeros(1, dtype=wp.int32, device=device)
    buffer = (segment_buffer(capacity, device) if capacity
              else reusable_buffer(static_grid, max(8 * count, 1024), device))
    pieces = []
    while count:
        buffer.cursor.zero_()
        wp.launch(dda_rays, dim=count, inputs=[static_grid.arrays, state, active, buffer],
                  device=device)
        written = min(int(buffer.cursor.numpy()[0]), buffer.capacity)
        if written:
            pieces.append(collect(buffer, written, device))
        cursor.zero_()
        wp.launch(_still_walking, dim=count, inputs=[state, active, spare, cursor],
                  device=device)
        active, spare = spare, active
        count = int(cursor.numpy()[0])
        if count and written == buffer.capacity:
            buffer = segment_buffer(2 * buffer.capacity, device)          # full: grow
    return segments_from(pieces, 0)
