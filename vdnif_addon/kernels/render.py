"""The neural render's device side: network inputs of walked segments, and hits made into
passes (DESIGN section 9).

A hit on segment ``(t0, t1, p0, p1)`` of cell ``cell`` at ``fraction`` of its length has the
deformed distance ``t0 + fraction (t1 - t0)``; its rest normal is carried to deformed space by
``J^-T``, J the Jacobian of the cell's trilinear map at the rest hit point, computed as
sign(det J) cof(J) n with J scaled to unit max entry, the rest normal kept where the
cofactor normal vanishes (the oracle ``deformed_normals`` in tests/oracles/geometry.py). The
renderer (``inference/neural_render.py``) and the embedded reference
(``tracing/references.py``, ``set_hits``) both make their passes here.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..geometry.attributes import FALLBACK_NORMAL, SINGULAR_COFACTOR
from . import runtime
from .cells import INF, CellArrays, cross, dot
from .segments import SegmentBuffer
from .walk import DONE, SEEK_FIRST, TRUNCATED, RayState

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    from .cells import DeviceCells

NO_HIT = wp.constant(np.iinfo(np.int32).max)
SINGULAR = wp.constant(wp.float64(SINGULAR_COFACTOR))
FALLBACK = wp.constant(wp.vec3d(*FALLBACK_NORMAL))


@wp.struct
class Passes:
    hit: wp.array(dtype=wp.int32)         # (R,) 1 where the ray hit
    distance: wp.array(dtype=wp.float64)  # (R,)
    normal: wp.array(dtype=wp.vec3d)      # (R,) unit, deformed space
    albedo: wp.array(dtype=wp.vec3)       # (R,)
    material: wp.array(dtype=wp.int32)    # (R,)
    cell: wp.array(dtype=wp.int32)        # (R,) the hit segment's cell, -1 for a miss


@wp.struct
class Prediction:
    """What the network says of each segment of a wave (torch tensors, shared)."""

    hit: wp.array(dtype=wp.int32)         # (S,) 1 above the model's occlusion threshold
    candidate: wp.array(dtype=wp.int32)   # (S,) 1 above its candidate threshold (<= the above)
    fraction: wp.array(dtype=wp.float64)  # (S,) hit position along the segment, 0..1
    normal: wp.array(dtype=wp.vec3d)      # (S,) rest-space normal
    material: wp.array(dtype=wp.int64)    # (S,)
    albedo: wp.array(dtype=wp.vec3)       # (S,) the albedo head, or empty
    table: wp.array(dtype=wp.vec3)        # (M,) albedo by material without an albedo head


@wp.struct
class WalkPast:
    """How a render walks rays on past the surface they leave (DESIGN section 9): a ray's
    hit within its reach, within ``within`` of where it started (walked past included), whose
    normal's dot product with ``leaving`` exceeds ``cosine``, is that surface met from below:
    the ray starts again ``step`` past it, in the hit's cell, at most ``times`` times (0:
    never; the arrays are then empty)."""

    leaving: wp.array(dtype=wp.vec3d)    # (R,) unit normals of the surfaces the rays leave
    origin: wp.array(dtype=wp.vec3d)     # (R,) the rays' origins, as given
    direction: wp.array(dtype=wp.vec3d)  # (R,) their directions, as given
    reach: wp.array(dtype=wp.float64)    # (R,) their max distances from those origins
    walked: wp.array(dtype=wp.float64)   # (R,) how far each started again past its origin
    skips: wp.array(dtype=wp.int32)      # (R,) how many times
    within: wp.float64
    step: wp.float64
    cosine: wp.float64
    times: wp.int32


@wp.func
def unit(x: wp.vec3d, fallback: wp.vec3d) -> wp.vec3d:
    """x / |x|, or ``fallback`` where |x| is zero or not finite (``attributes.normalize``)."""
    length = wp.sqrt(dot(x, x))
    if length > wp.float64(0.0) and length < wp.float64(np.inf):
        return x / length
    return fallback


@wp.func
def deformed_normal(cells: CellArrays, cell: wp.int32, point: wp.vec3d,
                    rest_normal: wp.vec3d) -> wp.vec3d:
    """normalize(J^-T n) at rest ``point`` of ``cell`` for rest normal n."""
    low = cells.rest[cells.cell_corners[cell, 0]]
    high = cells.rest[cells.cell_corners[cell, 7]]
    local = wp.vec3d()
    for axis in range(3):
        local[axis] = wp.clamp((point[axis] - low[axis]) / (high[axis] - low[axis]),
                               wp.float64(0.0), wp.float64(1.0))
    jacobian = wp.mat33d()
    for corner in range(8):
        x = cells.corners[cells.cell_corners[cell, corner]]
        for j in range(3):
            weight = wp.float64(1.0)
            for axis in range(3):
                if axis != j:
                    if (corner >> axis) & 1 == 1:
                        weight = weight * local[axis]
                    else:
                        weight = weight * (wp.float64(1.0) - local[axis])
            if (corner >> j) & 1 == 0:
                weight = -weight
            for i in range(3):
                jacobian[i, j] = jacobian[i, j] + x[i] * weight
    rest = unit(rest_normal, FALLBACK)
    scale = wp.float64(0.0)
    for i in range(3):
        for j in range(3):
            scale = wp.max(scale, wp.abs(jacobian[i, j]))
    if scale > wp.float64(0.0):
        jacobian = jacobian / scale
    a = wp.vec3d(jacobian[0, 0], jacobian[1, 0], jacobian[2, 0])
    b = wp.vec3d(jacobian[0, 1], jacobian[1, 1], jacobian[2, 1])
    c = wp.vec3d(jacobian[0, 2], jacobian[1, 2], jacobian[2, 2])
    bc = cross(b, c)
    deformed = bc * rest[0] + cross(c, a) * rest[1] + cross(a, b) * rest[2]
    if dot(a, bc) < wp.float64(0.0):
        deformed = -deformed
    if wp.sqrt(dot(deformed, deformed)) <= SINGULAR:
        return rest
    return unit(deformed, rest)


@wp.func
def write_hit(cells: CellArrays, passes: Passes, ray: wp.int32, cell: wp.int32,
              t0: wp.float64, t1: wp.float64, p0: wp.vec3d, p1: wp.vec3d,
              fraction: wp.float64, rest_normal: wp.vec3d, albedo: wp.vec3,
              material: wp.int32):
    """The hit's passes of ``ray`` except its hit flag, which the caller sets."""
    passes.distance[ray] = t0 + fraction * (t1 - t0)
    point = p0 + (p1 - p0) * fraction
    passes.normal[ray] = deformed_normal(cells, cell, point, rest_normal)
    passes.albedo[ray] = albedo
    passes.material[ray] = material
    passes.cell[ray] = cell


@wp.kernel(module=WARP_MODULE)
def _hits(cells: CellArrays, passes: Passes, ray: wp.array(dtype=wp.int32),
          cell: wp.array(dtype=wp.int32), t0: wp.array(dtype=wp.float64),
          t1: wp.array(dtype=wp.float64), p0: wp.array(dtype=wp.vec3d),
          p1: wp.array(dtype=wp.vec3d), fraction: wp.array(dtype=wp.float64),
          rest_normal: wp.array(dtype=wp.vec3d), albedo: wp.array(dtype=wp.vec3),
          material: wp.array(dtype=wp.int32)):
    i = wp.tid()
    write_hit(cells, passes, ray[i], cell[i], t0[i], t1[i], p0[i], p1[i], fraction[i],
              rest_normal[i], albedo[i], material[i])
    passes.hit[ray[i]] = 1


@wp.kernel(module=WARP_MODULE)
def network_inputs(out: SegmentBuffer, origin: wp.vec3d, extent: wp.float64,
                   p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3),
                   rest_length: wp.array(dtype=wp.float32)):
    """Segment end points normalized to the grid (``VoxelGrid.normalize``) and rest lengths,
    in float32 for the network; zeros past the segments written (a launch sized on the host
    before they were counted)."""
    s = wp.tid()
    if s >= wp.min(out.cursor[0], out.capacity):
        p0[s] = wp.vec3()
        p1[s] = wp.vec3()
        rest_length[s] = wp.float32(0.0)
        return
    a = out.p0[s]
    b = out.p1[s]
    na = (a - origin) / extent
    nb = (b - origin) / extent
    p0[s] = wp.vec3(wp.float32(na[0]), wp.float32(na[1]), wp.float32(na[2]))
    p1[s] = wp.vec3(wp.float32(nb[0]), wp.float32(nb[1]), wp.float32(nb[2]))
    rest_length[s] = wp.float32(wp.sqrt(dot(b - a, b - a)))


@wp.kernel(module=WARP_MODULE)
def first_hits(out: SegmentBuffer, prediction: Prediction, first: wp.array(dtype=wp.int32),
               candidate: wp.array(dtype=wp.int32)):
    """The earliest segment of each ray that the network says is hit, and the earliest
    candidate (a ray's segments take increasing slots in walk order)."""
    s = wp.tid()
    if s >= wp.min(out.cursor[0], out.capacity):
        return
    if prediction.candidate[s] != 0:
        wp.atomic_min(candidate, out.ray[s], s)
    if prediction.hit[s] != 0:
        wp.atomic_min(first, out.ray[s], s)


@wp.func
def walk_on_past(past: WalkPast, rays: RayState, passes: Passes,
                 placed: wp.array(dtype=wp.int32), r: wp.int32):
    """Ray ``r``, just made a hit: started again past it where ``past`` says the hit is the
    surface the ray left, its walk and its passes as a fresh ray's (the host's numbers: the
    start ``origin + walked direction``, the reach ``reach - walked``)."""
    walked = past.walked[r]
    distance = passes.distance[r]
    if not (distance <= past.reach[r] - walked and walked + distance <= past.within
            and dot(passes.normal[r], past.leaving[r]) > past.cosine):
        return
    walked = walked + (distance + past.step)
    past.walked[r] = walked
    past.skips[r] = past.skips[r] + 1
    rays.origin[r] = past.origin[r] + past.direction[r] * walked
    rays.far[r] = past.reach[r] - walked
    rays.start[r] = passes.cell[r]
    rays.mode[r] = SEEK_FIRST
    rays.cell[r] = 0
    rays.entry_face[r] = 0
    rays.zero_passes[r] = 0
    rays.steps[r] = 0
    rays.t[r] = wp.float64(0.0)
    rays.p[r] = wp.vec3d()
    rays.clip_from[r] = wp.float64(0.0)
    rays.behind_from[r] = -INF
    passes.hit[r] = 0
    placed[r] = 0


@wp.kernel(module=WARP_MODULE)
def resolve(cells: CellArrays, rays: RayState, active: wp.array(dtype=wp.int32),
            active_count: wp.array(dtype=wp.int32), out: SegmentBuffer,
            prediction: Prediction, first: wp.array(dtype=wp.int32),
            candidate: wp.array(dtype=wp.int32), placed: wp.array(dtype=wp.int32),
            has_albedo: wp.int32, passes: Passes, past: WalkPast):
    """The hit is placed on a ray's first candidate segment, in this wave or an earlier one
    (``placed``), and made a hit, ending the walk, by its first segment above the occlusion
    threshold (a candidate too, so never before the placed one); a hit on the surface the
    ray left starts it again past that surface (``WalkPast``)."""
    i = wp.tid()
    if i >= active_count[0]:
        return
    r = active[i]
    c = candidate[r]
    s = first[r]
    if c == NO_HIT:
        return
    candidate[r] = NO_HIT
    first[r] = NO_HIT
    if placed[r] == 0:
        material = wp.int32(prediction.material[c])
        albedo = wp.vec3()
        if has_albedo != 0:
            albedo = prediction.albedo[c]
        else:
            albedo = prediction.table[material]
        write_hit(cells, passes, r, out.cell[c], out.t0[c], out.t1[c], out.p0[c], out.p1[c],
                  prediction.fraction[c], prediction.normal[c], albedo, material)
        placed[r] = 1
    if s != NO_HIT:
        passes.hit[r] = 1
        rays.mode[r] = DONE
        if past.times > 0 and past.skips[r] < past.times:
            walk_on_past(past, rays, passes, placed, r)


def walk_past(leaving: Float[np.ndarray, "R 3"], origins: Float[np.ndarray, "R 3"],
              directions: Float[np.ndarray, "R 3"], reach: Float[np.ndarray, " R"],
              within: float, step: float, cosine: float, times: int, device: str) -> WalkPast:
    """A ``WalkPast`` on ``device`` for rays (R, 3) as given and their max distances (R,),
    leaving surfaces of unit normals ``leaving`` (R, 3) (``never_walk_past`` where no ray
    may)."""
    if times == 0 or len(origins) == 0:
        return never_walk_past(device)
    past = WalkPast()
    for name, values, dtype in (("leaving", leaving, wp.vec3d), ("origin", origins, wp.vec3d),
                                ("direction", directions, wp.vec3d),
                                ("reach", reach, wp.float64)):
        setattr(past, name, wp.array(np.asarray(values, np.float64), dtype=dtype,
                                     device=device))
    past.walked = wp.zeros(len(origins), dtype=wp.float64, device=device)
    past.skips = wp.zeros(len(origins), dtype=wp.int32, device=device)
    past.within, past.step, past.cosine = (wp.float64(within), wp.float64(step),
                                           wp.float64(cosine))
    past.times = wp.int32(times)
    return past


@functools.lru_cache(maxsize=None)
def never_walk_past(device: str) -> WalkPast:
    """The ``WalkPast`` of a render whose rays never walk past (``times`` 0, empty arrays):
    one per device, never written, so a render does not allocate it again."""
    past = WalkPast()
    for name, dtype in (("leaving", wp.vec3d), ("origin", wp.vec3d), ("direction", wp.vec3d),
                        ("reach", wp.float64), ("walked", wp.float64), ("skips", wp.int32)):
        setattr(past, name, wp.empty(0, dtype=dtype, device=device))
    past.within = past.step = past.cosine = wp.float64(0.0)
    past.times = wp.int32(0)
    return past


@wp.kernel(module=WARP_MODULE)
def count_segments(out: SegmentBuffer, totals: wp.array(dtype=wp.int32), index: wp.int32):
    """Adds the segments written to ``out`` to ``totals[index]`` (one thread), on the
    device."""
    totals[index] = totals[index] + wp.min(out.cursor[0], out.capacity)


@wp.kernel(module=WARP_MODULE)
def clear_misses(passes: Passes):
    """Rays that end with no segment above the occlusion threshold are misses: their
    passes lose what a candidate placed."""
    r = wp.tid()
    if passes.hit[r] == 0:
        passes.distance[r] = wp.float64(0.0)
        passes.normal[r] = wp.vec3d()
        passes.albedo[r] = wp.vec3()
        passes.material[r] = 0
        passes.cell[r] = -1


@wp.kernel(module=WARP_MODULE)
def unresolved_truncated(rays: RayState, passes: Passes, count: wp.array(dtype=wp.int32)):
    """Counts rays truncated without a hit."""
    r = wp.tid()
    if rays.mode[r] == TRUNCATED and passes.hit[r] == 0:
        wp.atomic_add(count, 0, 1)


def empty_passes(rays: int, device: str) -> Passes:
    """Device passes of ``rays`` rays (each array (rays,) or (rays, 3)), all zero."""
    passes = Passes()
    passes.hit = wp.zeros(rays, dtype=wp.int32, device=device)
    passes.distance = wp.zeros(rays, dtype=wp.float64, device=device)
    passes.normal = wp.zeros(rays, dtype=wp.vec3d, device=device)
    passes.albedo = wp.zeros(rays, dtype=wp.vec3, device=device)
    passes.material = wp.zeros(rays, dtype=wp.int32, device=device)
    passes.cell = wp.full(rays, -1, dtype=wp.int32, device=device)
    return passes


def write_hits(cells: DeviceCells, passes: Passes, ray: Int[np.ndarray, " H"],
               cell: Int[np.ndarray, " H"], t0: Float[np.ndarray, " H"],
               t1: Float[np.ndarray, " H"], p0: Float[np.ndarray, "H 3"],
               p1: Float[np.ndarray, "H 3"], fraction: Float[np.ndarray, " H"],
               rest_normal: Float[np.ndarray, "H 3"], albedo: Float[np.ndarray, "H 3"],
               material: Int[np.ndarray, " H"]) -> None:
    """Hits of rays ``ray`` (H,) from their hit segments (cell, t0, t1, p0, p1 (H,...)) at
    ``fraction`` (H,) with rest normals (H, 3), albedo (H, 3) and material (H,) into host
    ``Passes``."""
    count = len(ray)
    if count == 0:
        return
    device = cells.device
    runtime.load(WARP_MODULE, device)
    local = empty_passes(count, device)
    arrays = [wp.array(np.asarray(x, dtype), dtype=kind, device=device) for x, dtype, kind in (
        (np.arange(count), np.int32, wp.int32), (cell, np.int32, wp.int32),
        (t0, np.float64, wp.float64), (t1, np.float64, wp.float64),
        (p0, np.float64, wp.vec3d), (p1, np.float64, wp.vec3d),
        (fraction, np.float64, wp.float64), (rest_normal, np.float64, wp.vec3d),
        (albedo, np.float32, wp.vec3), (material, np.int32, wp.int32))]
    wp.launch(_hits, dim=count, inputs=[cells.arrays, local, *arrays], device=device)
    passes.hit[ray] = True
    passes.distance[ray] = local.distance.numpy()
    passes.normal[ray] = local.normal.numpy()
    passes.albedo[ray] = local.albedo.numpy()
    passes.material[ray] = local.material.numpy()
