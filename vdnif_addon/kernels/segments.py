"""The segment buffer the walks on a Warp device write to: the deformed walk
(``kernels/walk.py``) and the static DDA (``kernels/dda.py``) emit per-voxel segments into a
``SegmentBuffer`` on the device, and the host turns its pieces into ``walk_rules.Segments``.

Segments are written through one atomic cursor: on the CPU a launch runs its threads in
order, so segments come out grouped by ray in walk order; on CUDA a ray's own segments keep
their order and ``segments_from`` sorts by ray.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..geometry.walk_rules import Segments

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    Piece = tuple[Int[np.ndarray, " S"], Int[np.ndarray, " S"], Float[np.ndarray, " S"],
                  Float[np.ndarray, " S"], Float[np.ndarray, "S 3"], Float[np.ndarray, "S 3"]]
    """Host copies (ray, cell, t0, t1, p0, p1) of S segments of a SegmentBuffer."""


@wp.struct
class SegmentBuffer:
    ray: wp.array(dtype=wp.int32)
    cell: wp.array(dtype=wp.int32)
    t0: wp.array(dtype=wp.float64)
    t1: wp.array(dtype=wp.float64)
    p0: wp.array(dtype=wp.vec3d)
    p1: wp.array(dtype=wp.vec3d)
    cursor: wp.array(dtype=wp.int32)      # (1,) segments written (may overshoot capacity)
    capacity: wp.int32


@wp.func
def emit(out: SegmentBuffer, ray: wp.int32, cell: wp.int32, t0: wp.float64, t1: wp.float64,
         p0: wp.vec3d, p1: wp.vec3d) -> wp.int32:
    """Writes one segment; returns its slot, or -1 when the buffer is full."""
    slot = wp.atomic_add(out.cursor, 0, 1)
    if slot >= out.capacity:
        return -1
    out.ray[slot] = ray
    out.cell[slot] = cell
    out.t0[slot] = t0
    out.t1[slot] = t1
    out.p0[slot] = p0
    out.p1[slot] = p1
    return slot


def reusable_buffer(owner: object, capacity: int, device: str) -> SegmentBuffer:
    """A SegmentBuffer of at least ``capacity`` kept on ``owner`` between calls: a fresh one
    costs a page fault per 4 kB written (about 4 ms for a 256x256 view's segments on the
    CPU), every time."""
    buffer = getattr(owner, "_segment_buffer", None)
    if buffer is None or buffer.capacity < capacity or str(buffer.ray.device) != str(device):
        buffer = segment_buffer(capacity, device)
        owner._segment_buffer = buffer
    return buffer


def segment_buffer(capacity: int, device: str) -> SegmentBuffer:
    """An empty SegmentBuffer for ``capacity`` segments on ``device``."""
    buffer = SegmentBuffer()
    for name, dtype in (("ray", wp.int32), ("cell", wp.int32), ("t0", wp.float64),
                        ("t1", wp.float64), ("p0", wp.vec3d), ("p1", wp.vec3d)):
        setattr(buffer, name, wp.empty(capacity, dtype=dtype, device=device))
    buffer.cursor = wp.zeros(1, dtype=wp.int32, device=device)
    buffer.capacity = capacity
    return buffer


def collect(buffer: SegmentBuffer, count: int, device: str) -> Piece:
    """Host copies (ray, cell, t0, t1, p0, p1) of the first ``count`` segments of a buffer."""
    return tuple(getattr(buffer, name).numpy()[:count].copy()
                 for name in ("ray", "cell", "t0", "t1", "p0", "p1"))


def segments_from(pieces: Sequence[Piece], truncated: int) -> Segments:
    """Segments from host pieces in which each ray's segments come in walk order: ordered
    by ray, then distance, ties in walk order. A CPU launch writes them so already; a CUDA
    launch interleaves rays (a stable sort by ray restores them: 12 ms for 124 k segments
    on one CPU core, plus the gather)."""
    if pieces:
        ray, cell, t0, t1, p0, p1 = (np.concatenate(x) if len(pieces) > 1 else x[0]
                                     for x in zip(*pieces))
    else:
        ray = cell = np.empty(0, np.int32)
        t0 = t1 = np.empty(0)
        p0 = p1 = np.empty((0, 3))
    if np.any(np.diff(ray) < 0):
        order = np.argsort(ray, kind="stable")
        ray, cell, t0, t1, p0, p1 = (x[order] for x in (ray, cell, t0, t1, p0, p1))
    if np.any((np.diff(ray) == 0) & (np.diff(t0) < 0)):    # a walk that went back: rare
        order = np.lexsort((t0, ray))
        ray, cell, t0, t1, p0, p1 = (x[order] for x in (ray, cell, t0, t1, p0, p1))
    return Segments(ray=ray.astype(np.int64), cell=cell.astype(np.int64), t0=t0, t1=t1,
                    p0=p0, p1=p1, truncated=int(truncated))
