"""The deformation-aware walk as one Warp kernel: one thread per ray (DESIGN section 5).

Each ray keeps its walker state on the device between launches (``RayWalk``): seeking an
entry into the occupied set, walking a cell, done, or truncated. A launch advances every
listed ray until it is done, or has written ``per_wave`` segments (it pauses before its next
cell or seek, and ``RayWalk.drop_finished`` makes a paused seek), or the segment buffer is
full; the renderer uses the first bound (a wave of at most k segments per ray), ``traverse``
the last (it drains the buffer and goes on). The rules are those of the numpy walk this
kernel replaced (kept as the oracle in ``tests/oracles/walk.py``):

- entry and re-entry: the first boundary triangle of the entry BVH (``wp.mesh_query_ray``,
  float32) along the ray, its crossing refined in float64; a triangle the ray leaves by is
  passed (``step`` beyond it) and the cast repeated, at most ``SEEK_LIMIT`` times per seek,
  after which the ray is given up (truncated); on the first seek it means the ray starts
  inside, and it is walked from the backward cast's crossing and clipped at its origin; on
  a later seek, a leaving hit more than ``step`` beyond the seek start means the start is
  inside (a cell across an edge or corner of the cell left begins within ``step`` of the
  exit): the backward cast within ``2 step`` finds its entry, walked from there;
- a ray given the cell it is thought to start in (``RayState.start``) whose origin lies
  inside that cell or a face neighbour is walked from its entry into that cell, clipped at
  its origin, without the casts (``start_inside``); otherwise it seeks as above;
- in a cell: the exit is the nearest of the cell's face triangles (entry face skipped) that
  the ray crosses outward more than ``step`` beyond its entry, else the farthest one it
  touches; a zero-length pass counts, and after ``ZERO_PASS_LIMIT`` in a row, a lost walker
  (no exit) or an exit into an empty cell the ray re-seeks (a lost one past the farthest
  crossing of its cell);
- a ray's max distance ends it: the cell it crosses in is its last, recorded whole (a
  network answers whole cells; the caller compares the hit's distance with the limit); the
  first seek looks for the boundary ahead however far, so that a ray that starts inside
  walks its cells up to its limit even where the boundary lies beyond it;
- every ray makes at most ``max_steps`` cell steps; rays still walking then are truncated.

Segments are written to a ``kernels.segments.SegmentBuffer``, as the static DDA's are.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from .. import threads
from ..errors import VDNIFError
from ..geometry.walk_rules import SEEK_LIMIT, ZERO_PASS_LIMIT, step_budget
from . import runtime
from .cells import (
    INF,
    ONE_PLUS_TOLERANCE,
    TINY_SCALE,
    TOLERANCE,
    USABLE_DETERMINANT,
    CellArrays,
    boundary_crossing,
    cross,
    dot,
    entry_cast,
    intersect,
    maximum,
    rest_point,
)
from .segments import SegmentBuffer, collect, emit, reusable_buffer, segment_buffer, segments_from

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    from ..geometry.walk_rules import Segments
    from .cells import DeviceCells

UNLIMITED = np.iinfo(np.int32).max

# The walker's modes and its steps as Warp functions: seeking the next entry into the
# occupied set, finding a cell's exit, and where a walker that lost its way re-seeks from.
SEEK_FIRST = wp.constant(0)     # before the first entry: a leaving hit means "starts inside"
SEEK = wp.constant(1)           # looking for the next entry from ``t``
WALK = wp.constant(2)           # in ``cell``, entered at ``t`` / ``p`` through ``entry_face``
DONE = wp.constant(3)
TRUNCATED = wp.constant(4)      # out of steps, or a seek given up

SEEKS = wp.constant(SEEK_LIMIT)
ZERO_PASSES = wp.constant(ZERO_PASS_LIMIT)

@wp.func
def entry_behind(cells: CellArrays, o: wp.vec3d, d: wp.vec3d, cell: wp.int32):
    """Where the ray entered ``cell`` if its origin lies inside it: (found, t <= 0, face
    triangle 0..11, u, v). Inside: the ray leaves the cell by a face triangle ahead of its
    origin, and enters it by one at or behind the origin after the last it leaves by there;
    its entry is the first such (where a walk from behind, which exits at the first
    crossing outward, enters it)."""
    base = cell * 12
    left_t = -INF
    ahead = False
    for k in range(12):
        tri = cells.triangles[base + k]
        tk, _u, _v, hit, outward = intersect(o, d, tri.a, tri.e1, tri.e2, tri.scale)
        if hit and outward:
            if tk > wp.float64(0.0):
                ahead = True
            elif tk > left_t:
                left_t = tk
    entry = wp.int32(-1)
    entry_t = INF
    entry_u = wp.float64(0.0)
    entry_v = wp.float64(0.0)
    if ahead:
        for k in range(12):
            tri = cells.triangles[base + k]
            tk, u, v, hit, outward = intersect(o, d, tri.a, tri.e1, tri.e2, tri.scale)
            if hit and not outward and tk <= wp.float64(0.0) and tk > left_t and tk < entry_t:
                entry = k
                entry_t = tk
                entry_u = u
                entry_v = v
    return entry >= 0, entry_t, entry, entry_u, entry_v


@wp.func
def start_inside(cells: CellArrays, o: wp.vec3d, d: wp.vec3d, hint: wp.int32):
    """The cell among ``hint`` and its face neighbours whose inside holds the origin, with
    the ray's entry into it (``entry_behind``): (cell or -1, t, face triangle, u, v)."""
    found, t, k, u, v = entry_behind(cells, o, d, hint)
    if found:
        return hint, t, k, u, v
    for face in range(6):
        other = cells.neighbours[hint, face]
        if other >= 0:
            found, t, k, u, v = entry_behind(cells, o, d, other)
            if found:
                return other, t, k, u, v
    return wp.int32(-1), wp.float64(0.0), wp.int32(0), wp.float64(0.0), wp.float64(0.0)


@wp.func
def seek_entry(cells: CellArrays, o: wp.vec3d, d: wp.vec3d, far: wp.float64, mode: wp.int32,
               t: wp.float64, cell: wp.int32, entry_face: wp.int32, p: wp.vec3d,
               clip_from: wp.float64, behind_from: wp.float64):
    """The next entry into the occupied set at or after ``t`` (the entry rules in this
    module's docstring): (mode WALK, DONE or TRUNCATED, t, cell, entry face, rest entry
    point, clip_from, behind_from), the cell, face and point unchanged unless it entered."""
    step = cells.step
    casts = wp.int32(0)
    while mode != WALK and mode < DONE:
        if mode == SEEK and casts == SEEKS:
            mode = TRUNCATED                       # given up
            break
        casts += 1
        remaining = far - t
        if not (remaining >= wp.float64(0.0)):
            mode = DONE
            break
        reach = remaining
        if mode == SEEK_FIRST:
            reach = INF                            # whether it starts inside: the boundary
        found, face, cast_t = entry_cast(cells, o + d * t, d, reach)    # ahead, however far
        if not found:
            mode = DONE
            break
        hit_t, u, v, leaving = boundary_crossing(cells, o, d, face, cast_t + t)
        if mode == SEEK_FIRST:
            if leaving:                            # the ray starts inside
                found, back_face, back_t = entry_cast(cells, o, -d, INF)
                if found:
                    face = back_face
                    hit_t, u, v, leaving = boundary_crossing(cells, o, d, face, -back_t)
                    clip_from = hit_t
            leaving = False
            if hit_t > far:                        # it enters beyond its limit
                mode = DONE
                break
        elif leaving and hit_t > t + step and t > behind_from:
            # the seek starts inside the occupied set: a re-seek starts step beyond an exit,
            # and a cell across an edge or corner of the cell left can begin sooner; its
            # entry is within step behind the start (2 step: float32 slack), so it is
            # entered there instead of passing the far face. Once per seek start at most,
            # and only past the last such start: a collapsed cell entered so and left at
            # once would otherwise be entered forever
            found, back_face, back_t = entry_cast(cells, o + d * t, -d,
                                                  wp.float64(2.0) * step)
            if found:
                back_hit_t, back_u, back_v, back_leaving = boundary_crossing(
                    cells, o, d, back_face, t - back_t)
                if not back_leaving:
                    face = back_face
                    hit_t = maximum(back_hit_t, t - step)
                    u = back_u
                    v = back_v
                    leaving = False
                    behind_from = t
        if leaving:
            t = maximum(hit_t, t) + step
        else:
            triangle = cells.boundary_triangle[face]
            cell = cells.boundary_cell[face]
            entry_face = triangle // 2
            t = hit_t
            p = rest_point(cells, cell, triangle, u, v)
            mode = WALK
    return mode, t, cell, entry_face, p, clip_from, behind_from


@wp.func
def exit_crossings(cells: CellArrays, o: wp.vec3d, d: wp.vec3d, cell: wp.int32,
                   entry_face: wp.int32, t: wp.float64):
    """Outward crossings of the cell's face triangles (its entry face skipped): the nearest
    one beyond ``t + step`` and the farthest one at or after ``t - step``, each as (local
    triangle or -1, t, u, v)."""
    step = cells.step
    base = cell * 12
    ahead = wp.int32(-1)
    ahead_t = INF
    ahead_u = wp.float64(0.0)
    ahead_v = wp.float64(0.0)
    touch = wp.int32(-1)
    touch_t = -INF
    touch_u = wp.float64(0.0)
    touch_v = wp.float64(0.0)
    for k in range(12):
        if k // 2 != entry_face:
            tri = cells.triangles[base + k]
            pv = cross(d, tri.e2)
            det = dot(tri.e1, pv)
            if det < wp.float64(0.0) and -det > USABLE_DETERMINANT * wp.max(tri.scale,
                                                                          TINY_SCALE):
                inv = wp.float64(1.0) / det
                s = o - tri.a
                u = dot(s, pv) * inv
                if u >= -TOLERANCE:
                    q = cross(s, tri.e1)
                    v = dot(d, q) * inv
                    if v >= -TOLERANCE and u + v <= ONE_PLUS_TOLERANCE:
                        tk = dot(tri.e2, q) * inv
                        if tk > t + step and tk < ahead_t:
                            ahead = k
                            ahead_t = tk
                            ahead_u = u
                            ahead_v = v
                        if tk >= t - step and (touch < 0 or tk > touch_t):
                            touch = k
                            touch_t = tk
                            touch_u = u
                            touch_v = v
    return ahead, ahead_t, ahead_u, ahead_v, touch, touch_t, touch_u, touch_v


@wp.func
def farthest_crossing(cells: CellArrays, o: wp.vec3d, d: wp.vec3d, cell: wp.int32,
                      t: wp.float64) -> wp.float64:
    """The farthest crossing beyond ``t`` of any of the cell's face triangles (-inf if none):
    where a walker that lost its way re-seeks from."""
    base = cell * 12
    far_side = -INF
    for k in range(12):
        tri = cells.triangles[base + k]
        tk, _u, _v, hit, _outward = intersect(o, d, tri.a, tri.e1, tri.e2, tri.scale)
        if hit and tk > t and tk > far_side:
            far_side = tk
    return far_side



@wp.struct
class RayState:
    origin: wp.array(dtype=wp.vec3d)      # (R,)
    direction: wp.array(dtype=wp.vec3d)   # (R,) unit (zero for a zero direction)
    far: wp.array(dtype=wp.float64)       # (R,) max distance (-1: cast nothing)
    mode: wp.array(dtype=wp.int32)        # (R,) SEEK_FIRST .. TRUNCATED
    cell: wp.array(dtype=wp.int32)
    entry_face: wp.array(dtype=wp.int32)
    zero_passes: wp.array(dtype=wp.int32)
    steps: wp.array(dtype=wp.int32)
    t: wp.array(dtype=wp.float64)         # entry distance (WALK) or seek start (SEEK)
    p: wp.array(dtype=wp.vec3d)           # rest-space entry point (WALK)
    clip_from: wp.array(dtype=wp.float64)  # < 0: started inside, segments cut at 0
    behind_from: wp.array(dtype=wp.float64)  # seek start of the last entry found behind it
    start: wp.array(dtype=wp.int32)       # (R,) the cell the origin is thought in, or -1


@wp.kernel(module=WARP_MODULE)
def walk_rays(cells: CellArrays, rays: RayState, active: wp.array(dtype=wp.int32),
              active_count: wp.array(dtype=wp.int32), max_steps: wp.int32,
              per_wave: wp.int32, out: SegmentBuffer):
    i = wp.tid()
    if i >= active_count[0]:                # launched for more rays than are left
        return
    r = active[i]
    mode = rays.mode[r]
    if mode >= DONE:
        return
    o = rays.origin[r]
    d = rays.direction[r]
    far = rays.far[r]
    cell = rays.cell[r]
    entry_face = rays.entry_face[r]
    zero_passes = rays.zero_passes[r]
    steps = rays.steps[r]
    t = rays.t[r]
    p = rays.p[r]
    clip_from = rays.clip_from[r]
    behind_from = rays.behind_from[r]
    step = cells.step
    written = wp.int32(0)
    if mode == SEEK_FIRST and far >= wp.float64(0.0):
        hint = rays.start[r]
        if hint >= 0:
            inside, entry_t, k, u, v = start_inside(cells, o, d, hint)
            if inside >= 0:
                mode = WALK
                cell = inside
                entry_face = k // 2
                t = entry_t
                p = rest_point(cells, inside, k, u, v)
                clip_from = entry_t
                zero_passes = 0
    while mode < DONE:
        if written >= per_wave:
            # paused before a seek too: a wave's last segment often holds the ray's hit, and
            # the drop after the network seeks only for the rays it did not end
            break
        if mode != WALK:
            mode, t, cell, entry_face, p, clip_from, behind_from = seek_entry(
                cells, o, d, far, mode, t, cell, entry_face, p, clip_from, behind_from)
            if mode == WALK:
                zero_passes = 0
            continue
        if steps >= max_steps:
            mode = TRUNCATED
            break
        if out.cursor[0] >= out.capacity:
            break                                          # paused until the next launch
        ahead, ahead_t, ahead_u, ahead_v, touch, touch_t, touch_u, touch_v = exit_crossings(
            cells, o, d, cell, entry_face, t)
        exit_k = ahead
        exit_t = ahead_t
        exit_u = ahead_u
        exit_v = ahead_v
        if ahead < 0:
            exit_k = touch
            exit_t = touch_t
            exit_u = touch_u
            exit_v = touch_v
        lost = touch < 0
        far_side = -INF
        if lost:
            # no exit at all: the ray re-seeks past every crossing of the cell beyond t
            exit_t = t
            far_side = farthest_crossing(cells, o, d, cell, t)
        t_out = maximum(exit_t, t)
        beyond = t_out <= far
        p_out = p
        neighbour = wp.int32(-1)
        exit_face = wp.int32(0)
        if not lost:
            p_out = rest_point(cells, cell, exit_k, exit_u, exit_v)
            exit_face = exit_k // 2
            neighbour = cells.neighbours[cell, exit_face]
        if ahead >= 0 and t <= far and (not (clip_from < wp.float64(0.0))
                                      or t_out > wp.float64(0.0)):
            t0 = t
            p0 = p
            if clip_from < wp.float64(0.0) and t0 < wp.float64(0.0):
                p0 = p0 + (p_out - p0) * (-t0 / (t_out - t0))
                t0 = wp.float64(0.0)
            if emit(out, r, cell, t0, t_out, p0, p_out) < 0:
                break                                      # buffer full: redo this step later
            written += 1
        steps += 1
        if ahead >= 0:
            zero_passes = 0
        else:
            zero_passes += 1
        if (not lost) and beyond and neighbour >= 0 and zero_passes <= ZERO_PASSES:
            cell = neighbour
            entry_face = exit_face + 1 - 2 * (exit_face % 2)    # the opposite face
            t = t_out
            p = p_out
        elif beyond:
            if lost:
                t = maximum(far_side, t) + step
            else:
                t = t_out + step
            mode = SEEK
        else:
            mode = DONE
    rays.mode[r] = mode
    rays.cell[r] = cell
    rays.entry_face[r] = entry_face
    rays.zero_passes[r] = zero_passes
    rays.steps[r] = steps
    rays.t[r] = t
    rays.p[r] = p
    rays.clip_from[r] = clip_from
    rays.behind_from[r] = behind_from


@wp.kernel(module=WARP_MODULE)
def _still_walking(cells: CellArrays, rays: RayState, active: wp.array(dtype=wp.int32),
                   active_count: wp.array(dtype=wp.int32), keep: wp.array(dtype=wp.int32),
                   cursor: wp.array(dtype=wp.int32)):
    i = wp.tid()
    if i >= active_count[0]:
        return
    r = active[i]
    mode = rays.mode[r]
    if mode == SEEK:
        # a walker paused before a seek (its wave was full) seeks now, after the wave's
        # hits ended their rays: one that finds nothing leaves here, not a wave later
        mode, t, cell, entry_face, p, clip_from, behind_from = seek_entry(
            cells, rays.origin[r], rays.direction[r], rays.far[r], mode, rays.t[r],
            rays.cell[r], rays.entry_face[r], rays.p[r], rays.clip_from[r],
            rays.behind_from[r])
        if mode == WALK:
            rays.zero_passes[r] = 0
        rays.mode[r] = mode
        rays.t[r] = t
        rays.cell[r] = cell
        rays.entry_face[r] = entry_face
        rays.p[r] = p
        rays.clip_from[r] = clip_from
        rays.behind_from[r] = behind_from
    if mode < DONE:
        keep[wp.atomic_add(cursor, 0, 1)] = r


@wp.kernel(module=WARP_MODULE)
def _count_truncated(rays: RayState, count: wp.array(dtype=wp.int32)):
    if rays.mode[wp.tid()] == TRUNCATED:
        wp.atomic_add(count, 0, 1)


class Lane:
    """A list of unfinished rays on the device (order kept on the CPU): the first
    ``active_count[0]`` entries of ``active``. ``count`` is the host's copy of that count as
    of its last read (``drop_finished(read=True)``): after a drop without a read it is an
    upper bound, and launches over it skip the slots past the device's count."""

    def __init__(self, rays: Int[np.ndarray, " R"], device: str) -> None:
        self.active = wp.array(np.asarray(rays, np.int32), dtype=wp.int32, device=device)
        self._spare = wp.empty(len(rays), dtype=wp.int32, device=device)
        self.active_count = wp.full(1, len(rays), dtype=wp.int32, device=device)
        self._cursor = wp.zeros(1, dtype=wp.int32, device=device)
        self.count = len(rays)


class RayWalk:
    """The walker state of a set of rays through ``cells`` (a ``DeviceCells`` in its current
    pose) on the cells' device. The unfinished rays are split into ``lanes`` (ray i in lane
    i mod lanes) that can be walked separately: ``advance`` walks one lane on,
    ``drop_finished`` takes its finished rays out; ``count`` is the total left."""

    def __init__(self, cells: DeviceCells, origins: Float[np.ndarray, "N 3"],
                 directions: Float[np.ndarray, "N 3"],
                 max_distance: float | Float[np.ndarray, " N"] | None = None,
                 max_steps: int | None = None, lanes: int = 1,
                 start_cells: Int[np.ndarray, " N"] | None = None) -> None:
        runtime.load(WARP_MODULE, cells.device)
        origins = np.asarray(origins, np.float64)
        directions = np.asarray(directions, np.float64)
        norms = np.linalg.norm(directions, axis=1)
        directions = directions / np.where(norms > 0, norms, 1.0)[:, None]
        count = len(origins)
        far = np.full(count, np.inf) if max_distance is None else np.broadcast_to(
            np.asarray(max_distance, np.float64), (count,)).copy()
        far[norms == 0] = -1.0                              # no direction: no hit
        self.cells, self.device, self.rays = cells, cells.device, count
        self.max_steps = int(max_steps or step_budget(cells.cell_count))
        state = RayState()
        state.origin = wp.array(origins, dtype=wp.vec3d, device=self.device)
        state.direction = wp.array(directions, dtype=wp.vec3d, device=self.device)
        state.far = wp.array(far, dtype=wp.float64, device=self.device)
        for name, dtype in (("mode", wp.int32), ("cell", wp.int32), ("entry_face", wp.int32),
                            ("zero_passes", wp.int32), ("steps", wp.int32),
                            ("t", wp.float64), ("p", wp.vec3d), ("clip_from", wp.float64)):
            setattr(state, name, wp.zeros(count, dtype=dtype, device=self.device))
        state.behind_from = wp.array(np.full(count, -np.inf), dtype=wp.float64,
                                     device=self.device)
        start = np.full(count, -1, np.int32) if start_cells is None else _start_cells(
            start_cells, count, cells.cell_count)
        state.start = wp.array(start, dtype=wp.int32, device=self.device)
        self.state = state
        self.lanes = [Lane(np.arange(lane, count, lanes), self.device) for lane in range(lanes)]

    @property
    def count(self) -> int:
        return sum(lane.count for lane in self.lanes)

    def advance(self, out: SegmentBuffer, per_wave: int = UNLIMITED, lane: int = 0,
                read: bool = True) -> int | None:
        """Walks every unfinished ray of ``lane`` on until done, ``per_wave`` segments
        written, or ``out`` full; returns the number of segments now in ``out`` (written
        from slot ``out.cursor``, which the caller zeroes), read on the host, or None with
        ``read`` False (the count stays on the device: at most ``out.capacity``)."""
        rays = self.lanes[lane]
        if rays.count:
            wp.launch(walk_rays, dim=rays.count,
                      inputs=[self.cells.arrays, self.state, rays.active, rays.active_count,
                              self.max_steps, per_wave, out], device=self.device)
        if not read:
            return None
        return min(int(out.cursor.numpy()[0]), out.capacity)

    def drop_finished(self, lane: int = 0, read: bool = True) -> int:
        """Keeps only the unfinished rays in ``lane``, a ray paused before a seek seeking
        first (``walk_rays`` pauses there once its wave is full, so that a hit in the wave
        spares the cast); returns their count, read on the host, or with ``read`` False the
        host's bound on it (``Lane.count``, unchanged)."""
        rays = self.lanes[lane]
        if rays.count:
            rays._cursor.zero_()
            wp.launch(_still_walking, dim=rays.count,
                      inputs=[self.cells.arrays, self.state, rays.active, rays.active_count,
                              rays._spare, rays._cursor],
                      device=self.device)
            rays.active, rays._spare = rays._spare, rays.active
            rays.active_count, rays._cursor = rays._cursor, rays.active_count
            if read:
                rays.count = int(rays.active_count.numpy()[0])
        return rays.count

    def read_count(self, lane: int = 0) -> int:
        """``lane``'s unfinished rays, read from the device into ``Lane.count``."""
        rays = self.lanes[lane]
        if rays.count:
            rays.count = int(rays.active_count.numpy()[0])
        return rays.count

    def truncated(self) -> int:
        """Rays that ran out of steps or whose seek was given up."""
        counter = wp.zeros(1, dtype=wp.int32, device=self.device)
        if self.rays:
            wp.launch(_count_truncated, dim=self.rays, inputs=[self.state, counter],
                      device=self.device)
        return int(counter.numpy()[0])


def _start_cells(start_cells: Int[np.ndarray, " N"], rays: int, cell_count: int
                 ) -> Int[np.ndarray, " N"]:
    """``start_cells`` as int32, checked: one cell index (-1: none) per ray, each a cell of
    the grid (the kernel reads the cell's faces and neighbours)."""
    start = np.asarray(start_cells)
    if (start.shape != (rays,) or not np.issubdtype(start.dtype, np.integer)
            or (rays and (start.min() < -1 or start.max() >= cell_count))):
        raise VDNIFError(f"start cells need one integer in -1..{cell_count - 1} per ray "
                         f"({rays} rays), got {start.dtype} of shape {start.shape}"
                         + (f" from {start.min()} to {start.max()}"
                            if start.size and np.issubdtype(start.dtype, np.number) else ""))
    return start.astype(np.int32)


def walk_segments(cells: DeviceCells, origins: Float[np.ndarray, "N 3"],
                  directions: Float[np.ndarray, "N 3"],
                  max_distance: float | Float[np.ndarray, " N"] | None = None,
                  max_steps: int | None = None, capacity: int | None = None,
                  lanes: int = 1, start_cells: Int[np.ndarray, " N"] | None = None) -> Segments:
    """All Segments of the rays through ``cells`` (``traverse.traverse``), walked in
    ``lanes`` lanes at once, each on a thread of its own with a buffer of its own: the
    lanes hold disjoint rays and write disjoint memory (``kernels.launches``), and their
    segments, sorted by ray, are one lane's."""
    walk = RayWalk(cells, origins, directions, max_distance, max_steps, lanes=lanes,
                   start_cells=start_cells)
    size = capacity or max(8 * walk.rays // lanes, 1024)

    def walk_lane(lane: int) -> list:
        buffer = (reusable_buffer(cells, size, cells.device) if lane == 0 and not capacity
                  else segment_buffer(size, cells.device))
        pieces = []
        while walk.lanes[lane].count:
            buffer.cursor.zero_()
            written = walk.advance(buffer, lane=lane)
            if written:
                pieces.append(collect(buffer, written, cells.device))
            if walk.drop_finished(lane) and written == buffer.capacity:
                buffer = segment_buffer(2 * buffer.capacity, cells.device)    # full: grow
        return pieces

    lane_pieces = threads.at_once(walk_lane, lanes, "vdnif-walk")
    return segments_from([piece for pieces in lane_pieces for piece in pieces],
                         walk.truncated())
