"""The static DDA over the rest grid as one Warp kernel: one thread per ray.

Amanatides and Woo's walk through the uniform cells inside the occupied cells' bounds (no
entry BVH, no face intersections), recording the occupied cells as segments through the same
buffers and with the same per-ray state, launches and collection as the deformed walk
(``kernels/walk.py``), so the two compare like with like. The numbers are the numpy DDA's
that this kernel replaced (``tests/oracles/dda.py``): crossing distances ``(wall - o) / d``,
recomputed only on the axis that stepped, and end points ``o + t d``.
"""

from __future__ import annotations

import sys

import numpy as np
import warp as wp

from . import runtime
from .walk import SegmentBuffer, collect, emit, segment_buffer, segments_from

wp.set_module_options({"fuse_fp": False, "enable_backward": False})

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
def wall_crossing(grid: Grid, o: wp.vec3d, d: wp.vec3d, cell: wp.vec3i, axis: wp.int32):
    """Distance to the next cell wall along ``axis`` (inf for a ray parallel to it)."""
    if d[axis] == wp.float64(0.0):
        return INF
    up = wp.int32(0)
    if d[axis] > wp.float64(0.0):
        up = 1
    wall = grid.low[axis] + wp.float64(cell[axis] + up) * grid.voxel_size
    return (wall - o[axis]) / d[axis]


@wp.kernel
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
    if mode == ENTER:
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
        if not (valid and t < leave and t <= far):
            rays.mode[r] = DONE
            return
        point = o + d * t
        for axis in range(3):
            index = wp.int32(wp.floor((point[axis] - grid.low[axis]) / grid.voxel_size))
            cell[axis] = wp.clamp(index, 0, grid.dims[axis] - 1)
        mode = WALK
    crossing = wp.vec3d(wall_crossing(grid, o, d, cell, 0), wall_crossing(grid, o, d, cell, 1),
                        wall_crossing(grid, o, d, cell, 2))
    while mode == WALK:
        if out.cursor[0] >= out.capacity:
            break                                          # paused until the next launch
        axis = wp.int32(0)
        if crossing[1] < crossing[axis]:
            axis = 1
        if crossing[2] < crossing[axis]:
            axis = 2
        t_out = crossing[axis]
        index = grid.lookup[cell[0] + grid.dims[0] * (cell[1] + grid.dims[1] * cell[2])]
        within = t_out <= far
        if within and index >= 0 and t_out - t > grid.min_piece:
            if emit(out, r, index, t, t_out, o + d * t, o + d * t_out) < 0:
                break                                      # buffer full: redo this step later
        if d[axis] > wp.float64(0.0):
            cell[axis] = cell[axis] + 1
        else:
            cell[axis] = cell[axis] - 1
        if not (within and cell[axis] >= 0 and cell[axis] < grid.dims[axis]):
            mode = DONE
        t = wp.max(t_out, t)
        crossing[axis] = wall_crossing(grid, o, d, cell, axis)
    rays.mode[r] = mode
    rays.t[r] = t
    rays.cell[r] = cell


@wp.kernel
def _still_walking(rays: DDAState, active: wp.array(dtype=wp.int32),
                   keep: wp.array(dtype=wp.int32), cursor: wp.array(dtype=wp.int32)):
    r = active[wp.tid()]
    if rays.mode[r] != DONE:
        keep[wp.atomic_add(cursor, 0, 1)] = r


def dda_segments(static_grid, origins, directions, far, device, capacity=None):
    """Segments of rays (N, 3) with unit (or zero) ``directions`` and limits ``far`` (N,)
    through a ``dda.StaticGrid`` (its ``arrays`` on ``device``)."""
    runtime.load(sys.modules[__name__], device)
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
    buffer = segment_buffer(int(capacity or max(8 * count, 1024)), device)
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
