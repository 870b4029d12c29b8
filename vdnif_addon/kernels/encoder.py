"""The segment encoder psi = phi(gamma(x)) as one Warp kernel, and its backward as another.

DESIGN.md section 8. One launch encodes both end points of every segment: the positional
points ``gamma`` (x, then ``(sin(2^k s x) + 1) / 2`` and ``(cos(2^k s x) + 1) / 2`` per band
k), each looked up at every hash-grid level (trilinear, dense or hashed exactly as
``encoding.HashGrid`` lays out its table), written straight into the MLP's input row
``(end point, gamma point, level, feature)``. The backward recomputes the corners and
scatter-adds ``weight * output gradient`` into the table gradient (``wp::atomic_add``);
positions get no gradient.

Layout: task ``t`` encodes the end points ``[t B, (t + 1) B)`` of its launch, end point ``e``
being end ``e % ends`` of segment ``e // ends`` (``ends`` is 2 for segments, 1 for plain
points); ``B`` is ``CPU_BLOCK`` on the CPU and 1 on CUDA, where a task is a GPU thread. The
table is row-major ``(rows, Fd)``.

Why blocks, and why the body is C++ (``wp.func_native``, one source compiled for both
devices): Warp's CPU back end runs a kernel task after task in scalar code, so a lookup cost
about 30 ns, three quarters of it arithmetic (hashing eight corners, the weights, the
features). Within a block the lookups of one gamma point and level run as a loop over the
block's end points that the compiler vectorizes (``#pragma clang loop vectorize
(assume_safety)``, the promise that no two of its iterations touch the same memory):
hashing and weights for several end points at once, 8 in the 256-bit vectors clang picks
on an AVX-512 Xeon. The corners' rows are then read end point by end point, each row as one
vector of up to 4 features (clang's vector extension) that its weight scales and the sum
takes in; read across end points, a lookup's 24 floats took gathers, slower than these
plain loads (``docs/performance.md``). The backward adds to a row's features the same way.
On CUDA, whose compiler has no such vectors, the pragma is left out, a block is one end
point and a row is read feature by feature. The scalar kernel is the test oracle
(``tests/oracles/encoder_scalar.py``): features and table gradients equal its bits.

Arithmetic follows the torch reference (``tests/oracles/encoding_torch.py``) operation by
operation, in float32, without fused multiply-adds (module option ``fuse_fp`` off, which
reaches the C++ too): features equal it to a unit in the last place (the order of 8 float32
additions); vectorizing runs the same operations on several end points at once, in the same
order for each. A band's sin and cos are the correctly rounded float32 values of the
reference's angle; torch's float32 sin/cos (SLEEF) are sometimes one unit in the last place
off them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch
import warp as wp

from . import launches, runtime

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float, Int

LEVEL_FIELDS = 4
"""Per-level int32 parameters: resolution, first table row, y and z multipliers (bits)."""

MAX_LAUNCH_FLOATS = 2**31 - 1
"""Output floats of one launch at most: a launch's end points are counted in int32."""

CPU_BLOCK = 64
"""End points a CPU task encodes, its vectorized loops' trip count: 16 gave 0.93x the
throughput of 64 and 256 0.84x (the paper's setting, 16,384 segments, one CPU thread); the
block's points and corners live on the task's stack (about 9 kB)."""

CPU_SCATTER_BLOCK = 16
"""End points a CPU task of the backward takes: its corners of ``PAIRS`` pairs live on the
task's stack (34 kB at 16); 4 gave 0.64x the throughput of 16 and 64 0.77x (as above)."""

PAIRS = 32
"""(Gamma point, level) pairs whose corners a backward task keeps before it scatters."""

# sin and cos of band 0's angle, a lambda that the gamma points' loop calls (in the test of
# its roundings too).
BAND_SINCOS = r"""
// sin and cos of band 0's angle x, for |x| <= SINCOS_REACH: x less the nearest multiple of
// pi/2 (Cody and Waite's reduction, pi/2 in three parts, n pi/2's first part exact), then
// fdlibm's polynomials on [-pi/4, pi/4] and the quadrant. Within a unit in the last place of
// libm's, so the bands' float32 values are libm's but where a value lies that close to a
// float32 rounding boundary; unlike a libm call, the compiler vectorizes it. A larger or
// non-finite angle takes libm's (the caller's loop).
constexpr double SINCOS_REACH = 65536.0;
auto band_sincos = [](double angle, double& sine, double& cosine) {
    const double x = wp::abs(angle) <= SINCOS_REACH ? angle : 0.0;
    const double fn = (double)(long long)(x * 6.36619772367581382433e-01
                                          + (x < 0.0 ? -0.5 : 0.5));
    const double t = x - fn * 1.57079632673412561417e+00;
    double w = fn * 6.07710050630396597660e-11;
    const double r = t - w;
    w = fn * 2.02226624879595063154e-21 - ((t - r) - w);
    const double y0 = r - w;
    const double y1 = (r - y0) - w;
    const double z = y0 * y0;
    const double v = z * y0;
    const double rs = 8.33333333332248946124e-03 + z * (-1.98412698298579493134e-04
        + z * (2.75573137070700676789e-06 + z * (-2.50507602534068634195e-08
        + z * 1.58969099521155010221e-10)));
    const double ks = y0 - ((z * (0.5 * y1 - v * rs) - y1) - v * -1.66666666666666324348e-01);
    const double rc = z * (4.16666666666666019037e-02 + z * (-1.38888888888741095749e-03
        + z * (2.48015872894767294178e-05 + z * (-2.75573143513906633035e-07
        + z * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11)))));
    const double ay = wp::abs(y0);
    // beyond 0.3 the sum is split at qx (few bits: 1 - qx is exact)
    const double qx = ay > 0.78125 ? 0.28125 : (double)(float)(0.25 * ay);
    const double kc = ay < 0.3 ? 1.0 - (0.5 * z - (z * rc - y0 * y1))
                               : (1.0 - qx) - ((0.5 * z - qx) - (z * rc - y0 * y1));
    const int quadrant = (int)((long long)fn & 3);
    sine = quadrant == 0 ? ks : quadrant == 1 ? kc : quadrant == 2 ? -ks : -kc;
    cosine = quadrant == 0 ? kc : quadrant == 1 ? -ks : quadrant == 2 ? -kc : ks;
};
"""

# The C++ shared by the forward and the backward. A task's block: the end points' raw
# coordinates ``raw``, band sines and cosines ``sn``/``cs`` in float64 (band k's from band
# k - 1's by the double angle), the current gamma point ``pt`` clamped to [0, 1] (NaN as 0), and at
# each level its 8 corners' table rows and trilinear weights, corner ``4i + 2j + k`` being
# vertex ``cell + (i, j, k)``.
_BLOCK = BAND_SINCOS + r"""
#if defined(__CUDA_ARCH__)
constexpr int BLOCK = 1;
#define VDNIF_SIMD
#else
constexpr int BLOCK = %(cpu_block)d;
#define VDNIF_SIMD _Pragma("clang loop vectorize(assume_safety)")
#endif
const int first = task * BLOCK;
int n = count - first;
if (n > BLOCK) n = BLOCK;
if (n <= 0) return 0;
const float* P0 = (const float*)p0.data;
const float* P1 = (const float*)p1.data;
const int* LV = (const int*)levels.data;
const int L = levels.shape[0] / %(fields)d;
const int G = 1 + 2 * bands;
const long long width = (long long)G * L * fd;
float raw[3][BLOCK], pt[3][BLOCK];
double sn[3][BLOCK], cs[3][BLOCK];
for (int i = 0; i < n; ++i) {
    const int e = first + i;
    const float* src = ((e & (ends - 1)) == 1 ? P1 : P0) + 3 * (long long)(e >> (ends - 1));
    for (int k = 0; k < 3; ++k) raw[k][i] = src[k];
}
"""

_GAMMA = r"""
    for (int k = 0; k < 3; ++k) {
        if (g == 0) {
            for (int i = 0; i < n; ++i) pt[k][i] = raw[k][i];
        } else if (g == 1) {
            VDNIF_SIMD
            for (int i = 0; i < n; ++i) {
                double sine, cosine;
                band_sincos((double)(raw[k][i] * scale), sine, cosine);
                sn[k][i] = sine;
                cs[k][i] = cosine;
            }
            for (int i = 0; i < n; ++i) {
                const double angle = (double)(raw[k][i] * scale);
                if (!(wp::abs(angle) <= SINCOS_REACH)) {
                    sn[k][i] = wp::sin(angle);
                    cs[k][i] = wp::cos(angle);
                }
                pt[k][i] = ((float)sn[k][i] + 1.0f) * 0.5f;
            }
        } else if (g & 1) {
            VDNIF_SIMD
            for (int i = 0; i < n; ++i) {
                const double s = sn[k][i], c = cs[k][i];
                sn[k][i] = (s * c) * 2.0;
                cs[k][i] = (c - s) * (c + s);
                pt[k][i] = ((float)sn[k][i] + 1.0f) * 0.5f;
            }
        } else {
            for (int i = 0; i < n; ++i) pt[k][i] = ((float)cs[k][i] + 1.0f) * 0.5f;
        }
        VDNIF_SIMD
        for (int i = 0; i < n; ++i) {
            float v = pt[k][i];
            v = v != v ? 0.0f : v;
            pt[k][i] = wp::min(wp::max(v, 0.0f), 1.0f);
        }
    }
"""

_CORNERS = r"""
        const float res = (float)LV[%(fields)d * l];
        const float last = res - 1.0f;
        const int start = LV[%(fields)d * l + 1];
        const unsigned int my = (unsigned int)LV[%(fields)d * l + 2];
        const unsigned int mz = (unsigned int)LV[%(fields)d * l + 3];
        const bool hashed = l >= dense;
        VDNIF_SIMD
        for (int i = 0; i < n; ++i) {
            const float x = pt[0][i] * res, y = pt[1][i] * res, z = pt[2][i] * res;
            const float cx = wp::min(wp::floor(x), last);
            const float cy = wp::min(wp::floor(y), last);
            const float cz = wp::min(wp::floor(z), last);
            const float fx = x - cx, fy = y - cy, fz = z - cz;
            const unsigned int x0 = (unsigned int)(int)cx;
            const unsigned int y0 = (unsigned int)(int)cy * my;
            const unsigned int z0 = (unsigned int)(int)cz * mz;
            const unsigned int x1 = x0 + 1u, y1 = y0 + my, z1 = z0 + mz;
            // dense: x + y (res+1) + z (res+1)^2; hashed (instant-ngp):
            // (x * 1 ^ y * 2654435761 ^ z * 805459861) mod 2^T in wrapping uint32 arithmetic
            const unsigned int a = hashed ? x0 ^ y0 : x0 + y0;
            const unsigned int b = hashed ? x0 ^ y1 : x0 + y1;
            const unsigned int c = hashed ? x1 ^ y0 : x1 + y0;
            const unsigned int d = hashed ? x1 ^ y1 : x1 + y1;
            const unsigned int keep = hashed ? (unsigned int)mask : 0xFFFFFFFFu;
            rows[0][i] = start + (int)((hashed ? a ^ z0 : a + z0) & keep);
            rows[1][i] = start + (int)((hashed ? a ^ z1 : a + z1) & keep);
            rows[2][i] = start + (int)((hashed ? b ^ z0 : b + z0) & keep);
            rows[3][i] = start + (int)((hashed ? b ^ z1 : b + z1) & keep);
            rows[4][i] = start + (int)((hashed ? c ^ z0 : c + z0) & keep);
            rows[5][i] = start + (int)((hashed ? c ^ z1 : c + z1) & keep);
            rows[6][i] = start + (int)((hashed ? d ^ z0 : d + z0) & keep);
            rows[7][i] = start + (int)((hashed ? d ^ z1 : d + z1) & keep);
            // each weight (wx * wy) * wz, as the reference forms it
            const float gx = 1.0f - fx, gy = 1.0f - fy, gz = 1.0f - fz;
            const float w00 = gx * gy, w01 = gx * fy, w10 = fx * gy, w11 = fx * fy;
            w[0][i] = w00 * gz;
            w[1][i] = w00 * fz;
            w[2][i] = w01 * gz;
            w[3][i] = w01 * fz;
            w[4][i] = w10 * gz;
            w[5][i] = w10 * fz;
            w[6][i] = w11 * gz;
            w[7][i] = w11 * fz;
        }
"""

# On the CPU a corner's row (its features f0 .. f0 + M - 1, M <= 4 a literal, so that the
# loads are plain) times its weight, summed in corner order as the scalar kernel sums each
# feature: lane f holds feature f0 + f's sum, and the unused lanes add zeros.
_FORWARD_SNIPPET = _BLOCK + r"""
#if !defined(__CUDA_ARCH__)
typedef float FEATURES __attribute__((ext_vector_type(4)));
#define VDNIF_ROW(c, M) {                                                                  \
    const float* t = TABLE + rows[c][i] * fd + f0;                                      \
    const FEATURES r = {t[0], M > 1 ? t[1] : 0.0f, M > 2 ? t[2] : 0.0f,                 \
                        M > 3 ? t[3] : 0.0f};                                           \
    acc = c == 0 ? r * w[c][i] : acc + r * w[c][i];                                     \
}
#define VDNIF_FEATURES(M)                                                                  \
    for (int i = 0; i < n; ++i) {                                                       \
        FEATURES acc;                                                                   \
        VDNIF_ROW(0, M) VDNIF_ROW(1, M) VDNIF_ROW(2, M) VDNIF_ROW(3, M)                 \
        VDNIF_ROW(4, M) VDNIF_ROW(5, M) VDNIF_ROW(6, M) VDNIF_ROW(7, M)                 \
        const long long o = chunk + i * width;                                          \
        VDNIF_PUT(o, acc.x);                                                            \
        if (M > 1) VDNIF_PUT(o + 1, acc.y);                                             \
        if (M > 2) VDNIF_PUT(o + 2, acc.z);                                             \
        if (M > 3) VDNIF_PUT(o + 3, acc.w);                                             \
    }
#endif
const float* TABLE = (const float*)table.data;
// the features in float32, or rounded to bfloat16 (to nearest, ties to even: as torch
// rounds them for a layer that multiplies in bfloat16)
float* OUT = (float*)out.data;
wp::bfloat16* OUT16 = (wp::bfloat16*)out16.data;
#define VDNIF_PUT(at, value) {                                                         \
    if (bf16) OUT16[at] = wp::bfloat16(value); else OUT[at] = value;                    \
}
int rows[8][BLOCK];
float w[8][BLOCK];
for (int g = 0; g < G; ++g) {
""" + _GAMMA + r"""
    for (int l = 0; l < L; ++l) {
""" + _CORNERS + r"""
#if defined(__CUDA_ARCH__)
        for (int f = 0; f < fd; ++f) {
            const long long column = (long long)first * width + (long long)(g * L + l) * fd + f;
            for (int i = 0; i < n; ++i) {
                float acc = TABLE[rows[0][i] * fd + f] * w[0][i];
                acc = acc + TABLE[rows[1][i] * fd + f] * w[1][i];
                acc = acc + TABLE[rows[2][i] * fd + f] * w[2][i];
                acc = acc + TABLE[rows[3][i] * fd + f] * w[3][i];
                acc = acc + TABLE[rows[4][i] * fd + f] * w[4][i];
                acc = acc + TABLE[rows[5][i] * fd + f] * w[5][i];
                acc = acc + TABLE[rows[6][i] * fd + f] * w[6][i];
                acc = acc + TABLE[rows[7][i] * fd + f] * w[7][i];
                VDNIF_PUT(column + i * width, acc);
            }
        }
#else
        for (int f0 = 0; f0 < fd; f0 += 4) {
            const long long chunk = (long long)first * width + (long long)(g * L + l) * fd + f0;
            switch (fd - f0) {
                case 1: VDNIF_FEATURES(1) break;
                case 2: VDNIF_FEATURES(2) break;
                case 3: VDNIF_FEATURES(3) break;
                default: VDNIF_FEATURES(4) break;
            }
        }
#endif
    }
}
#undef VDNIF_PUT
return 0;
"""

# The backward keeps the corners of up to ``PAIRS`` (gamma point, level) pairs of its block and
# then scatters end point by end point, pair by pair, corner by corner: one end point's order
# as a task of one end point would add them, so a table row's float32 additions come in the
# same order whatever the blocks (and training is the same bit for bit at any block size)
# wherever a point has at most ``PAIRS`` pairs (the paper's setting: 14). The scatter is not
# vectorized: two end points of a block may share a corner.
_BACKWARD_SNIPPET = _BLOCK + r"""
#if defined(__CUDA_ARCH__)
constexpr int PAIRS = 1;
#else
constexpr int PAIRS = %(pairs)d;
#endif
#if !defined(__CUDA_ARCH__)
// A corner's row gets features f0 .. f0 + M - 1 of the output gradient times its weight, in
// corner order: each table value's additions come in the order of a feature-by-feature loop.
#define VDNIF_SCATTER(M) {                                                                 \
    const float v0 = VDNIF_GET(column + f0);                                            \
    const float v1 = M > 1 ? VDNIF_GET(column + f0 + 1) : 0.0f;                         \
    const float v2 = M > 2 ? VDNIF_GET(column + f0 + 2) : 0.0f;                         \
    const float v3 = M > 3 ? VDNIF_GET(column + f0 + 3) : 0.0f;                         \
    for (int corner = 0; corner < 8; ++corner) {                                        \
        float* t = GRAD + kept_rows[q][corner][i] * fd + f0;                            \
        const float weight = kept_w[q][corner][i];                                      \
        t[0] = t[0] + v0 * weight;                                                      \
        if (M > 1) t[1] = t[1] + v1 * weight;                                           \
        if (M > 2) t[2] = t[2] + v2 * weight;                                           \
        if (M > 3) t[3] = t[3] + v3 * weight;                                           \
    }                                                                                   \
}
#endif
// the output gradient in float32 or bfloat16 (each value exact in float32)
const float* GRAD_OUT = (const float*)grad_out.data;
const wp::bfloat16* GRAD_OUT16 = (const wp::bfloat16*)grad_out16.data;
#define VDNIF_GET(at) (bf16 ? (float)GRAD_OUT16[at] : GRAD_OUT[at])
float* GRAD = (float*)grad_table.data;
int kept_rows[PAIRS][8][BLOCK];
float kept_w[PAIRS][8][BLOCK];
int kept_pair[PAIRS];
int kept = 0;
for (int g = 0; g < G; ++g) {
""" + _GAMMA + r"""
    for (int l = level_first; l < level_stop; ++l) {
        auto& rows = kept_rows[kept];
        auto& w = kept_w[kept];
""" + _CORNERS + r"""
        kept_pair[kept] = g * L + l;
        ++kept;
        if (kept == PAIRS || (g == G - 1 && l == level_stop - 1)) {
            for (int i = 0; i < n; ++i) {
                const long long row = (long long)(first + i) * width;
                for (int q = 0; q < kept; ++q) {
                    const long long column = row + (long long)kept_pair[q] * fd;
#if defined(__CUDA_ARCH__)
                    for (int f = 0; f < fd; ++f) {
                        const float value = VDNIF_GET(column + f);
                        for (int corner = 0; corner < 8; ++corner)
                            wp::atomic_add(GRAD + kept_rows[q][corner][i] * fd + f,
                                           value * kept_w[q][corner][i]);
                    }
#else
                    for (int f0 = 0; f0 < fd; f0 += 4) {
                        switch (fd - f0) {
                            case 1: VDNIF_SCATTER(1) break;
                            case 2: VDNIF_SCATTER(2) break;
                            case 3: VDNIF_SCATTER(3) break;
                            default: VDNIF_SCATTER(4) break;
                        }
                    }
#endif
                }
            }
            kept = 0;
        }
    }
}
#undef VDNIF_GET
return 0;
"""

@wp.func_native(_FORWARD_SNIPPET % {"cpu_block": CPU_BLOCK, "fields": LEVEL_FIELDS})
def _encode_block(
    task: int, count: int, p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3),
    ends: int, bands: int, scale: float, dense: int, mask: wp.uint32,
    levels: wp.array(dtype=wp.int32), table: wp.array(dtype=wp.float32), fd: int,
    out: wp.array(dtype=wp.float32), out16: wp.array(dtype=wp.bfloat16), bf16: int,
) -> int: ...


@wp.func_native(_BACKWARD_SNIPPET % {"cpu_block": CPU_SCATTER_BLOCK, "fields": LEVEL_FIELDS,
                                     "pairs": PAIRS})
def _scatter_block(
    task: int, count: int, p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3),
    ends: int, bands: int, scale: float, dense: int, mask: wp.uint32,
    levels: wp.array(dtype=wp.int32), level_first: int, level_stop: int,
    grad_out: wp.array(dtype=wp.float32), grad_out16: wp.array(dtype=wp.bfloat16), bf16: int,
    fd: int, grad_table: wp.array(dtype=wp.float32),
) -> int: ...


@wp.kernel(module=WARP_MODULE)
def _encode(
    count: int, p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), ends: int,
    bands: int, scale: float, dense: int, mask: wp.uint32, levels: wp.array(dtype=wp.int32),
    table: wp.array(dtype=wp.float32), fd: int, out: wp.array(dtype=wp.float32),
    out16: wp.array(dtype=wp.bfloat16), bf16: int,
):
    _encode_block(wp.tid(), count, p0, p1, ends, bands, scale, dense, mask, levels, table, fd,
                  out, out16, bf16)


@wp.kernel(module=WARP_MODULE)
def _encode_backward(
    count: int, p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), ends: int,
    bands: int, scale: float, dense: int, mask: wp.uint32, levels: wp.array(dtype=wp.int32),
    level_first: int, level_stop: int, grad_out: wp.array(dtype=wp.float32),
    grad_out16: wp.array(dtype=wp.bfloat16), bf16: int, fd: int,
    grad_table: wp.array(dtype=wp.float32),
):
    _scatter_block(wp.tid(), count, p0, p1, ends, bands, scale, dense, mask, levels,
                   level_first, level_stop, grad_out, grad_out16, bf16, fd, grad_table)


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


def _block(device: str, cpu_block: int) -> int:
    """End points a task takes on ``device`` (its snippet's ``BLOCK``): 1 on CUDA."""
    return cpu_block if str(device).startswith("cpu") else 1


def _launches(enc: Encoding, p0: Float[torch.Tensor, "N 3"],
              p1: Float[torch.Tensor, "N 3"] | None, ends: int, block: int, parts: int = 1
              ) -> list[tuple[int, int, int, list[Any]]]:
    """Slices ``(first, stop)`` of the points, at least ``parts`` of them (as even as may be)
    and of at most ``MAX_LAUNCH_FLOATS`` output floats each, with each slice's task count
    (tasks of ``block`` end points) and its launch arguments up to the levels."""
    shared = [enc.bands, float(enc.scale), enc.dense, wp.uint32(enc.mask),
              wp.from_torch(enc.levels, requires_grad=False, return_ctype=True)]
    slices = launches.bounds(p0.shape[0], parts, MAX_LAUNCH_FLOATS // enc.width(ends))
    return [(first, stop, -(-(stop - first) * ends // block),
             [(stop - first) * ends]
             + [_vec3(p[first:stop]) for p in (p0, p0 if p1 is None else p1)]
             + [ends] + shared)
            for first, stop in slices]


def _vec3(points: Float[torch.Tensor, "N 3"]):
    """(N, 3) float32 as a Warp array descriptor (no wp.array object: cheaper per launch)."""
    return wp.from_torch(points, dtype=wp.vec3, requires_grad=False, return_ctype=True)


FEATURE_DTYPES = (torch.float32, torch.bfloat16)
"""What the encoder writes its features in and reads their gradient from."""


def _floats(t: torch.Tensor):
    """A contiguous float32 tensor as a 1-D Warp float array (through a flat view: a size-1
    dimension may carry any stride)."""
    return wp.from_torch(t.view(-1), dtype=wp.float32, requires_grad=False,
                         return_ctype=True)


def _features(t: torch.Tensor) -> list[Any]:
    """A contiguous float32 or bfloat16 tensor as the kernels' three arguments for it: the
    float32 array, the bfloat16 array (one of the two empty) and whether it is bfloat16."""
    half = t.dtype == torch.bfloat16
    empty = t.new_empty(0, dtype=torch.float32 if half else torch.bfloat16)
    float32, bfloat16 = (empty, t) if half else (t, empty)
    return [_floats(float32),
            wp.from_torch(bfloat16.view(-1), dtype=wp.bfloat16, requires_grad=False,
                          return_ctype=True),
            int(half)]


def encode(enc: Encoding, table: Float[torch.Tensor, "rows Fd"], p0: Float[torch.Tensor, "N 3"],
           p1: Float[torch.Tensor, "N 3"] | None, dtype: torch.dtype = torch.float32
           ) -> Float[torch.Tensor, "N C"]:
    """Features (N, C) of points (``p1`` None: C = L*Fd, no gamma unless bands) or segments
    (C = 2*(1+2F)*L*Fd); table (rows, Fd) float32 contiguous, p0/p1 (N, 3) contiguous
    float32, all on one device. Computed in float32 and written in ``dtype``
    (``FEATURE_DTYPES``: bfloat16 rounds them to nearest, ties to even, as torch's
    conversion does). Each output row is written by its own slice's launch."""
    if dtype not in FEATURE_DTYPES:
        raise ValueError(f"the encoder writes float32 or bfloat16 features, not {dtype}")
    ends = 1 if p1 is None else 2
    out = torch.empty(p0.shape[0], enc.width(ends), dtype=dtype, device=p0.device)
    device, stream = _target(p0)
    rows = _floats(table)
    parts = launches.parts(device, p0.shape[0])
    slices = _launches(enc, p0, p1, ends, _block(device, CPU_BLOCK), parts)
    launches.run(_encode, device, stream, parts,
                 [(tasks, args + [rows, enc.feature_dim] + _features(out[first:stop]))
                  for first, stop, tasks, args in slices])
    return out


def encode_backward(enc: Encoding, rows: int, p0: Float[torch.Tensor, "N 3"],
                    p1: Float[torch.Tensor, "N 3"] | None, grad_out: Float[torch.Tensor, "N C"]
                    ) -> Float[torch.Tensor, "rows Fd"]:
    """d(sum grad_out * encode(...)) / d table: (rows, Fd) float32; grad_out (N, C), read as
    it is in float32 or bfloat16 (any other dtype converted to float32).

    Workers that run at once scatter the levels of their own (a level's rows are its own,
    and a CPU launch's atomic adds are plain adds, safe within one serial launch only), every
    point each, into one table: a row's additions then come in one launch's order (where a
    point has at most ``PAIRS`` pairs). A grid of one level takes one worker."""
    ends = 1 if p1 is None else 2
    device, stream = _target(p0)
    if grad_out.dtype not in FEATURE_DTYPES:
        grad_out = grad_out.to(torch.float32)
    grad_out = grad_out.contiguous()
    count = enc.levels.shape[0] // LEVEL_FIELDS
    levels = launches.bounds(count, min(launches.parts(device, p0.shape[0]), count))
    slices = _launches(enc, p0, p1, ends, _block(device, CPU_SCATTER_BLOCK))
    grads = torch.zeros(rows, enc.feature_dim, dtype=torch.float32, device=p0.device)
    # job i runs on worker i % len(levels) (launches.run): each worker keeps its levels and
    # takes the slices in order
    launches.run(_encode_backward, device, stream, len(levels),
                 [(tasks, args + [level_first, level_stop] + _features(grad_out[first:stop])
                   + [enc.feature_dim, _floats(grads)])
                  for first, stop, tasks, args in slices
                  for level_first, level_stop in levels])
    return grads
