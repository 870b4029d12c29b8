"""The segment encoder psi = phi(gamma(x)) as one Warp kernel, and its backward as another.

DESIGN.md section 8. One launch encodes both end points of every segment: the positional
points ``gamma`` (x, then ``(sin(2^k s x) + 1) / 2`` and ``(cos(2^k s x) + 1) / 2`` per band
k), each looked up at every hash-grid level (trilinear, dense or hashed exactly as
``encoding.HashGrid`` lays out its table), written straight into the MLP's input row
``(end point, gamma point, level, feature)``. The backward recomputes the corners and
scatter-adds ``weight * output gradient`` into the table gradient (``wp.atomic_add``);
positions get no gradient.

Layout: thread ``t`` encodes end point ``t % ends`` of segment ``t // ends`` (``ends`` is 2
for segments, 1 for plain points), all its ``1 + 2F`` gamma points. The table is row-major,
``(rows, Fd)``, read as one vector of ``K`` floats per access (``K`` the largest of 4, 3, 2, 1
dividing Fd; ``Fd / K`` chunks per row): one 12-byte load per corner at Fd = 3, 1.2-1.5x the
throughput of a per-float loop over a runtime Fd on the row-major table and 1.3-1.6x that of
the feature-major ``(Fd, rows)`` table of model format 1 (``tools/encoder_bench.py``, paper
setting, one CPU thread). Every array is 1-D, so Warp's contiguous-array specialization makes
its strides constants.

Arithmetic follows the torch reference (``tests/oracles/encoding_torch.py``) operation by
operation, in float32, without fused multiply-adds (module option ``fuse_fp`` off): features
equal it to a unit in the last place (the order of 8 float32 additions). A band's sin and
cos are the correctly rounded float32 values of the reference's angle; torch's float32
sin/cos (SLEEF) are sometimes one unit in the last place off them.

On the CPU a launch is serial and latency-bound on the table reads: at the paper's setting
(two 2^16-row levels, 1.5 MB) a 2^8-row table encodes 1.3-1.5x faster.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch
import warp as wp

from . import launches, runtime

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float, Int

# No automatic adjoints (the backward is written by hand) and no contraction into fused
# multiply-adds, which would round differently from the torch reference.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

LEVEL_FIELDS = 4
"""Per-level int32 parameters: resolution, first table row, y and z multipliers (bits)."""

MAX_LAUNCH_VECTORS = 2**31 - 1
"""Output vectors of one launch at most: the kernels index them with int32."""

NON_NEGATIVE = 0x7FFFFFFF
"""Masks an array index known to be in [0, 2^31): Warp wraps negative indices Python-style,
and an index whose sign bit is visibly clear lets the compiler drop that test, 4 instructions
per table read (1.05-1.08x the throughput, tools/encoder_bench.py)."""

VECTOR_WIDTHS = (4, 3, 2, 1)
"""Table-row access widths compiled, widest first: a row of Fd floats is read as Fd / K
vectors of the widest K that divides Fd."""


@wp.func
def _unit(v: float):
    """A coordinate as the grid reads it: NaN as 0, clamped to [0, 1]."""
    if v != v:
        v = 0.0
    return wp.min(wp.max(v, 0.0), 1.0)


@wp.func
def _wave(v: wp.vec3d):
    """A sinusoid's value as a gamma point: rounded to float32, then ``(v + 1) / 2`` in float32
    as the reference computes it."""
    return (wp.vec3(v) + wp.vec3(1.0)) * 0.5


_Rows = wp.types.vector(length=8, dtype=wp.int32)
_Weights = wp.types.vector(length=8, dtype=wp.float32)


@wp.func
def _corners(
    px: float, py: float, pz: float, level: int, dense: int, mask: wp.uint32,
    levels: wp.array(dtype=wp.int32),
):
    """Table rows of a point's 8 cell corners at one level, in corner order ``4i + 2j + k``
    (vertex ``cell + (i, j, k)``), and its fractions within the cell; px, py, pz in [0,1]."""
    res = float(levels[LEVEL_FIELDS * level])
    last = res - 1.0
    x = px * res
    y = py * res
    z = pz * res
    cx = wp.min(wp.floor(x), last)
    cy = wp.min(wp.floor(y), last)
    cz = wp.min(wp.floor(z), last)
    frac = wp.vec3(x - cx, y - cy, z - cz)
    start = levels[LEVEL_FIELDS * level + 1]
    sy = wp.uint32(levels[LEVEL_FIELDS * level + 2])
    sz = wp.uint32(levels[LEVEL_FIELDS * level + 3])
    x0 = wp.uint32(int(cx))
    y0 = wp.uint32(int(cy)) * sy
    z0 = wp.uint32(int(cz)) * sz
    x1 = x0 + wp.uint32(1)
    y1 = y0 + sy
    z1 = z0 + sz
    if level < dense:
        # dense: x + y (res+1) + z (res+1)^2
        a = x0 + y0
        b = x0 + y1
        c = x1 + y0
        d = x1 + y1
        return _Rows(
            start + int(a + z0), start + int(a + z1), start + int(b + z0),
            start + int(b + z1), start + int(c + z0), start + int(c + z1),
            start + int(d + z0), start + int(d + z1),
        ), frac
    # hashed (instant-ngp): (x * 1 ^ y * 2654435761 ^ z * 805459861) mod 2^T in wrapping
    # uint32 arithmetic; sy, sz hold the primes' bits
    a = x0 ^ y0
    b = x0 ^ y1
    c = x1 ^ y0
    d = x1 ^ y1
    return _Rows(
        start + int((a ^ z0) & mask), start + int((a ^ z1) & mask),
        start + int((b ^ z0) & mask), start + int((b ^ z1) & mask),
        start + int((c ^ z0) & mask), start + int((c ^ z1) & mask),
        start + int((d ^ z0) & mask), start + int((d ^ z1) & mask),
    ), frac


@wp.func
def _weights(frac: wp.vec3):
    """Trilinear weights in corner order, each ``(wx * wy) * wz`` as the reference forms it."""
    gx = 1.0 - frac[0]
    gy = 1.0 - frac[1]
    gz = 1.0 - frac[2]
    w00 = gx * gy
    w01 = gx * frac[1]
    w10 = frac[0] * gy
    w11 = frac[0] * frac[1]
    return _Weights(
        w00 * gz, w00 * frac[2], w01 * gz, w01 * frac[2],
        w10 * gz, w10 * frac[2], w11 * gz, w11 * frac[2],
    )


@wp.func
def _encode_point(
    point: wp.vec3, column: int, dense: int, mask: wp.uint32,
    levels: wp.array(dtype=wp.int32), table: wp.array(dtype=Any), chunks: int,
    out: wp.array(dtype=Any),
):
    """Features of one gamma point at every level into ``out[column:]`` (vector units)."""
    px = _unit(point[0])
    py = _unit(point[1])
    pz = _unit(point[2])
    for level in range(levels.shape[0] // LEVEL_FIELDS):
        rows, frac = _corners(px, py, pz, level, dense, mask, levels)
        w = _weights(frac)
        for j in range(chunks):
            acc = table[(rows[0] * chunks + j) & NON_NEGATIVE] * w[0]
            acc = acc + table[(rows[1] * chunks + j) & NON_NEGATIVE] * w[1]
            acc = acc + table[(rows[2] * chunks + j) & NON_NEGATIVE] * w[2]
            acc = acc + table[(rows[3] * chunks + j) & NON_NEGATIVE] * w[3]
            acc = acc + table[(rows[4] * chunks + j) & NON_NEGATIVE] * w[4]
            acc = acc + table[(rows[5] * chunks + j) & NON_NEGATIVE] * w[5]
            acc = acc + table[(rows[6] * chunks + j) & NON_NEGATIVE] * w[6]
            acc = acc + table[(rows[7] * chunks + j) & NON_NEGATIVE] * w[7]
            out[(column + level * chunks + j) & NON_NEGATIVE] = acc
    return 0


@wp.func
def _scatter_point(
    point: wp.vec3, column: int, dense: int, mask: wp.uint32,
    levels: wp.array(dtype=wp.int32), grad_out: wp.array(dtype=Any), chunks: int,
    grad_table: wp.array(dtype=Any),
):
    """Adds ``weight * grad_out`` of one gamma point's features to its corners' rows."""
    px = _unit(point[0])
    py = _unit(point[1])
    pz = _unit(point[2])
    for level in range(levels.shape[0] // LEVEL_FIELDS):
        rows, frac = _corners(px, py, pz, level, dense, mask, levels)
        w = _weights(frac)
        for j in range(chunks):
            g = grad_out[(column + level * chunks + j) & NON_NEGATIVE]
            for c in range(8):
                wp.atomic_add(grad_table, (rows[c] * chunks + j) & NON_NEGATIVE, g * w[c])
    return 0


@wp.func
def _first_band(p: wp.vec3, scale: float):
    """sin and cos of band 0's angles ``x * s`` (formed in float32 as the reference forms
    them), in float64."""
    angle = wp.vec3d(p * scale)
    return wp.vec3d(wp.sin(angle[0]), wp.sin(angle[1]), wp.sin(angle[2])), wp.vec3d(
        wp.cos(angle[0]), wp.cos(angle[1]), wp.cos(angle[2]))


@wp.func
def _next_band(s: wp.vec3d, c: wp.vec3d):
    """sin and cos of twice the angle: 2 s c and (c - s)(c + s)."""
    return wp.cw_mul(s, c) * wp.float64(2.0), wp.cw_mul(c - s, c + s)


# Gamma: band k's angle is x * (s 2^k), formed in float32 as the reference does, which is
# exactly 2^k times band 0's float32 angle. Its sin and cos follow from band 0's by the
# double-angle formulas in float64 (error ~2^k * 1e-16, far below float32's 6e-8), so each
# rounds to the float32 sin/cos of the reference's angle: 6 library calls per end point
# instead of 6F (1.1-1.25x the throughput at F = 3, measured on one CPU thread).


@wp.kernel(module=WARP_MODULE)
def _encode(
    p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), ends: int, bands: int,
    scale: float, dense: int, mask: wp.uint32, levels: wp.array(dtype=wp.int32),
    table: wp.array(dtype=Any), chunks: int, out: wp.array(dtype=Any),
):
    tid = wp.tid()
    n = tid >> (ends - 1)
    end = tid & (ends - 1)
    p = p0[n]
    if end == 1:
        p = p1[n]
    step = (levels.shape[0] // LEVEL_FIELDS) * chunks  # vectors per gamma point
    column = (n * ends + end) * (1 + 2 * bands) * step
    _encode_point(p, column, dense, mask, levels, table, chunks, out)
    if bands > 0:
        s, c = _first_band(p, scale)
        for _k in range(bands):
            column += step
            _encode_point(_wave(s), column, dense, mask, levels, table, chunks, out)
            column += step
            _encode_point(_wave(c), column, dense, mask, levels, table, chunks, out)
            s, c = _next_band(s, c)


@wp.kernel(module=WARP_MODULE)
def _encode_backward(
    p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), ends: int, bands: int,
    scale: float, dense: int, mask: wp.uint32, levels: wp.array(dtype=wp.int32),
    grad_out: wp.array(dtype=Any), chunks: int, grad_table: wp.array(dtype=Any),
):
    tid = wp.tid()
    n = tid >> (ends - 1)
    end = tid & (ends - 1)
    p = p0[n]
    if end == 1:
        p = p1[n]
    step = (levels.shape[0] // LEVEL_FIELDS) * chunks
    column = (n * ends + end) * (1 + 2 * bands) * step
    _scatter_point(p, column, dense, mask, levels, grad_out, chunks, grad_table)
    if bands > 0:
        s, c = _first_band(p, scale)
        for _k in range(bands):
            column += step
            _scatter_point(_wave(s), column, dense, mask, levels, grad_out, chunks, grad_table)
            column += step
            _scatter_point(_wave(c), column, dense, mask, levels, grad_out, chunks, grad_table)
            s, c = _next_band(s, c)


_VECTORS = {width: wp.types.vector(length=width, dtype=wp.float32) for width in VECTOR_WIDTHS}
# Every width's overload in the one module (a single compile), each launched as itself: no
# argument-type inference per launch.
_FORWARD = {
    width: wp.overload(_encode, {"table": wp.array(dtype=vector), "out": wp.array(dtype=vector)})
    for width, vector in _VECTORS.items()
}
_BACKWARD = {
    width: wp.overload(_encode_backward, {"grad_out": wp.array(dtype=vector),
                                          "grad_table": wp.array(dtype=vector)})
    for width, vector in _VECTORS.items()
}


def vector_width(feature_dim: int) -> int:
    """Floats per table access for a row of ``feature_dim`` floats."""
    return next(width for width in VECTOR_WIDTHS if feature_dim % width == 0)


class Encoding:
    """What a launch needs to know of the grid and gamma: ``levels`` (L*4,) int32 per-level
    parameters (``LEVEL_FIELDS``) on the launch device, ``dense`` (the dense levels are the
    first ones), ``mask`` = 2^T - 1, ``feature_dim``, ``bands`` and frequency ``scale``."""

    __slots__ = ("levels", "dense", "mask", "feature_dim", "bands", "scale")

    def __init__(self, levels: Int[torch.Tensor, " L*4"], dense: int, mask: int,
                 feature_dim: int, bands: int, scale: float) -> None:
        self.levels, self.dense, self.mask = levels, dense, mask
        self.feature_dim, self.bands, self.scale = feature_dim, bands, scale

    def width(self, ends: int) -> int:
        """Floats per encoded row: ends * (1 + 2F) * L * Fd."""
        count = self.levels.shape[0] // LEVEL_FIELDS
        return ends * (1 + 2 * self.bands) * count * self.feature_dim


def _target(tensor: torch.Tensor) -> tuple[str, wp.Stream | None]:
    """(Warp device, stream) of a torch tensor's device, the kernels loaded there. On CUDA the
    launch goes to torch's current stream, so it is ordered with torch's work; what the host
    reads of its output (through torch) waits for that stream."""
    device = runtime.device(tensor.device)
    runtime.load(WARP_MODULE, device)
    if tensor.device.type != "cuda":
        return device, None
    return device, launches.warp_stream(torch.cuda.current_stream(tensor.device))


def _launches(enc: Encoding, p0: Float[torch.Tensor, "N 3"],
              p1: Float[torch.Tensor, "N 3"] | None, ends: int, parts: int = 1
              ) -> list[tuple[int, int, list[Any]]]:
    """Slices ``(first, stop)`` of the points, at least ``parts`` of them (as even as may be)
    and of at most ``MAX_LAUNCH_VECTORS`` output vectors each, with the launch arguments of
    the slice."""
    per_point = enc.width(ends) // vector_width(enc.feature_dim)
    shared = [ends, enc.bands, float(enc.scale), enc.dense, wp.uint32(enc.mask),
              wp.from_torch(enc.levels, requires_grad=False, return_ctype=True)]
    return [(first, stop, [_vec3(p[first:stop]) for p in (p0, p0 if p1 is None else p1)]
             + shared)
            for first, stop in launches.bounds(p0.shape[0], parts,
                                               MAX_LAUNCH_VECTORS // per_point)]


def _vec3(points: Float[torch.Tensor, "N 3"]):
    """(N, 3) float32 as a Warp array descriptor (no wp.array object: cheaper per launch)."""
    return wp.from_torch(points, dtype=wp.vec3, requires_grad=False, return_ctype=True)


def _vectors(t: torch.Tensor, width: int):
    """A contiguous float32 tensor as a 1-D Warp array of ``width``-float vectors (through a
    flat view: a size-1 dimension may carry any stride)."""
    return wp.from_torch(t.view(-1).view(-1, width), dtype=_VECTORS[width],
                         requires_grad=False, return_ctype=True)


def encode(enc: Encoding, table: Float[torch.Tensor, "rows Fd"], p0: Float[torch.Tensor, "N 3"],
           p1: Float[torch.Tensor, "N 3"] | None) -> Float[torch.Tensor, "N C"]:
    """Features (N, C) of points (``p1`` None: C = L*Fd, no gamma unless bands) or segments
    (C = 2*(1+2F)*L*Fd); table (rows, Fd) float32 contiguous, p0/p1 (N, 3) contiguous
    float32, all on one device. Each output row is written by its own slice's launch."""
    ends = 1 if p1 is None else 2
    out = torch.empty(p0.shape[0], enc.width(ends), dtype=torch.float32, device=p0.device)
    device, stream = _target(p0)
    width = vector_width(enc.feature_dim)
    rows = _vectors(table, width)
    chunks = enc.feature_dim // width
    parts = launches.parts(device, p0.shape[0])
    slices = _launches(enc, p0, p1, ends, parts)
    launches.run(_FORWARD[width], device, stream, parts,
                 [((stop - first) * ends, args + [rows, chunks, _vectors(out[first:stop], width)])
                  for first, stop, args in slices])
    return out


def encode_backward(enc: Encoding, rows: int, p0: Float[torch.Tensor, "N 3"],
                    p1: Float[torch.Tensor, "N 3"] | None, grad_out: Float[torch.Tensor, "N C"]
                    ) -> Float[torch.Tensor, "rows Fd"]:
    """d(sum grad_out * encode(...)) / d table: (rows, Fd) float32; grad_out (N, C).

    Workers that run at once scatter into gradient tables of their own (a CPU launch's
    atomic adds are plain adds, safe within one serial launch only), summed afterwards: the
    sum's order then differs from one launch's, by float32 rounding."""
    ends = 1 if p1 is None else 2
    device, stream = _target(p0)
    width = vector_width(enc.feature_dim)
    grad_out = grad_out.to(torch.float32).contiguous()
    chunks = enc.feature_dim // width
    parts = launches.parts(device, p0.shape[0])
    slices = _launches(enc, p0, p1, ends, parts)
    grads = torch.zeros(parts, rows, enc.feature_dim, dtype=torch.float32, device=p0.device)
    launches.run(_BACKWARD[width], device, stream, parts,
                 [((stop - first) * ends,
                   args + [_vectors(grad_out[first:stop], width), chunks,
                           _vectors(grads[i % parts], width)])
                  for i, (first, stop, args) in enumerate(slices)])
    return grads[0] if parts == 1 else grads.sum(0)
