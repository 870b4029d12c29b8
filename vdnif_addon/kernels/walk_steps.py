"""The steps of the deformed walk (``walk.py``'s kernel) as Warp functions: seeking the next
entry into the occupied set, finding a cell's exit, and where a walker that lost its way
re-seeks from; with the walker's modes. The rules are in ``walk.py``'s docstring."""

import warp as wp

from ..geometry.walk_rules import SEEK_LIMIT, ZERO_PASS_LIMIT
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

wp.set_module_options({"fuse_fp": False, "enable_backward": False})

SEEK_FIRST = wp.constant(0)     # before the first entry: a leaving hit means "starts inside"
SEEK = wp.constant(1)           # looking for the next entry from ``t``
WALK = wp.constant(2)           # in ``cell``, entered at ``t`` / ``p`` through ``entry_face``
DONE = wp.constant(3)
TRUNCATED = wp.constant(4)      # out of steps, or a seek given up

SEEKS = wp.constant(SEEK_LIMIT)
ZERO_PASSES = wp.constant(ZERO_PASS_LIMIT)

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
