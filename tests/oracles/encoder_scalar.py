"""The scalar Warp encoder the block encoder replaced (``vdnif_addon/kernels/encoder.py``),
kept as the test oracle: one thread per end point, every lookup in scalar code, its backward
scattering end point by end point. The block encoder must equal it bit for bit, features and
table gradients (the same operations in the same order, only run on several end points at
once).

``encode`` / ``encode_backward`` take the product's ``Encoding`` and launch once on the CPU.
"""

from __future__ import annotations

from typing import Any

import torch
import warp as wp

from vdnif_addon.kernels.encoder import LEVEL_FIELDS

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

NON_NEGATIVE = 0x7FFFFFFF
"""Masks an array index known to be in [0, 2^31) (as the kernel did)."""

VECTOR_WIDTHS = (4, 3, 2, 1)
"""Table-row access widths, widest first: a row of Fd floats read as Fd / K vectors."""


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


@wp.kernel
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


@wp.kernel
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


def _width(feature_dim: int) -> int:
    return next(width for width in VECTOR_WIDTHS if feature_dim % width == 0)


def _vectors(t: torch.Tensor, width: int):
    return wp.from_torch(t.contiguous().view(-1).view(-1, width), dtype=_VECTORS[width],
                         requires_grad=False)


def _arguments(enc, p0, p1):
    ends = 1 if p1 is None else 2
    points = [wp.from_torch(p.contiguous(), dtype=wp.vec3, requires_grad=False)
              for p in (p0, p0 if p1 is None else p1)]
    return ends, points + [ends, enc.bands, float(enc.scale), enc.dense, wp.uint32(enc.mask),
                           wp.from_torch(enc.levels, requires_grad=False)]


def encode(enc, table: torch.Tensor, p0: torch.Tensor, p1: torch.Tensor | None) -> torch.Tensor:
    """Features (N, C) as the scalar kernel computed them, on the CPU."""
    ends, args = _arguments(enc, p0, p1)
    width = _width(enc.feature_dim)
    out = torch.empty(p0.shape[0], enc.width(ends), dtype=torch.float32)
    wp.launch(_FORWARD[width], dim=p0.shape[0] * ends, device="cpu",
              inputs=args + [_vectors(table, width), enc.feature_dim // width,
                             _vectors(out, width)])
    return out


def encode_backward(enc, rows: int, p0: torch.Tensor, p1: torch.Tensor | None,
                    grad_out: torch.Tensor) -> torch.Tensor:
    """The table gradient (rows, Fd) as the scalar kernel scattered it, on the CPU."""
    ends, args = _arguments(enc, p0, p1)
    width = _width(enc.feature_dim)
    grad = torch.zeros(rows, enc.feature_dim, dtype=torch.float32)
    wp.launch(_BACKWARD[width], dim=p0.shape[0] * ends, device="cpu",
              inputs=args + [_vectors(grad_out.float(), width), enc.feature_dim // width,
                             _vectors(grad, width)])
    return grad
