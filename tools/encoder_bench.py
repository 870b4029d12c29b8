"""Table layouts of the encoder kernel, measured: the product's row-major table read as one
vector per corner, against a row-major table read float by float over a runtime Fd, and the
feature-major table ``(Fd, rows)`` of model format 1 (one cache line per feature).

    .venv/bin/python tools/encoder_bench.py [--segments 65536] [--repeats 21]

Forward only, the paper's setting (L = 2, N_min = 64, T = 16, Fd = 3, F = 3), random segments;
each variant's launch is timed in this thread's CPU time (a Warp CPU launch runs on the
calling thread), the variants alternating, and the minimum and median reported. The variants
other than the product's live here only: they share its corner, weight and gamma functions.
"""

import argparse
import pathlib
import statistics
import sys
import time

import torch
import warp as wp

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from vdnif_addon.kernels import encoder, runtime  # noqa: E402
from vdnif_addon.kernels.encoder import (
    LEVEL_FIELDS,
    _corners,
    _first_band,
    _next_band,
    _unit,
    _wave,
    _weights,
)
from vdnif_addon.model.encoding import HashGrid  # noqa: E402

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.func
def _point(point: wp.vec3, column: int, dense: int, mask: wp.uint32,
           levels: wp.array(dtype=wp.int32), table: wp.array(dtype=wp.float32),
           row_stride: int, feature_stride: int, fd: int, out: wp.array(dtype=wp.float32)):
    px = _unit(point[0])
    py = _unit(point[1])
    pz = _unit(point[2])
    for level in range(levels.shape[0] // LEVEL_FIELDS):
        rows, frac = _corners(px, py, pz, level, dense, mask, levels)
        w = _weights(frac)
        for f in range(fd):
            o = f * feature_stride
            acc = table[rows[0] * row_stride + o] * w[0]
            acc = acc + table[rows[1] * row_stride + o] * w[1]
            acc = acc + table[rows[2] * row_stride + o] * w[2]
            acc = acc + table[rows[3] * row_stride + o] * w[3]
            acc = acc + table[rows[4] * row_stride + o] * w[4]
            acc = acc + table[rows[5] * row_stride + o] * w[5]
            acc = acc + table[rows[6] * row_stride + o] * w[6]
            acc = acc + table[rows[7] * row_stride + o] * w[7]
            out[column + level * fd + f] = acc
    return 0


@wp.kernel
def _scalar_encode(p0: wp.array(dtype=wp.vec3), p1: wp.array(dtype=wp.vec3), bands: int,
                   scale: float, dense: int, mask: wp.uint32, levels: wp.array(dtype=wp.int32),
                   table: wp.array(dtype=wp.float32), row_stride: int, feature_stride: int,
                   fd: int, out: wp.array(dtype=wp.float32)):
    """The product kernel's work with the table as floats: element (row, f) at
    ``row * row_stride + f * feature_stride``."""
    tid = wp.tid()
    n = tid >> 1
    p = p0[n]
    if (tid & 1) == 1:
        p = p1[n]
    step = (levels.shape[0] // LEVEL_FIELDS) * fd
    column = tid * (1 + 2 * bands) * step
    _point(p, column, dense, mask, levels, table, row_stride, feature_stride, fd, out)
    if bands > 0:
        s, c = _first_band(p, scale)
        for _k in range(bands):
            column += step
            _point(_wave(s), column, dense, mask, levels, table, row_stride, feature_stride,
                   fd, out)
            column += step
            _point(_wave(c), column, dense, mask, levels, table, row_stride, feature_stride,
                   fd, out)
            s, c = _next_band(s, c)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--segments", type=int, default=2**16)
    parser.add_argument("--repeats", type=int, default=21)
    args = parser.parse_args()
    torch.manual_seed(0)
    grid = HashGrid(2, 64, 2.0, 16, 3)
    with torch.no_grad():
        grid.table.uniform_(-1, 1)
    enc = grid.encoding(3, 1.0)
    p0, p1 = torch.rand(2, args.segments, 3)
    runtime.load(sys.modules[__name__], "cpu")
    rows, fd = grid.table.shape
    row_major = grid.table.detach().contiguous()
    feature_major = row_major.t().contiguous()
    out = torch.empty(args.segments, enc.width(2))
    shared = [wp.from_torch(p0, dtype=wp.vec3), wp.from_torch(p1, dtype=wp.vec3), enc.bands,
              enc.scale, enc.dense, wp.uint32(enc.mask), wp.from_torch(enc.levels)]

    def scalar(table, row_stride, feature_stride):
        flat = wp.from_torch(table.view(-1), requires_grad=False)
        target = wp.from_torch(out.view(-1))
        return lambda: wp.launch(_scalar_encode, dim=2 * args.segments, device="cpu",
                                 inputs=shared + [flat, row_stride, feature_stride, fd, target])

    variants = {
        "row-major, vector per corner (product)": lambda: encoder.encode(enc, row_major, p0, p1),
        "row-major, float loop over runtime Fd": scalar(row_major, fd, 1),
        "feature-major (Fd, rows), float loop": scalar(feature_major, 1, rows),
    }
    reference = encoder.encode(enc, row_major, p0, p1)
    for name, run in variants.items():
        run()
        if name != next(iter(variants)):
            assert torch.equal(out, reference), name
    times = {name: [] for name in variants}
    for _ in range(args.repeats):
        for name, run in variants.items():
            started = time.thread_time()
            run()
            times[name].append(time.thread_time() - started)
    for name, seconds in times.items():
        print(f"{name:40s} min {args.segments / min(seconds) / 1e6:5.2f}  median "
              f"{args.segments / statistics.median(seconds) / 1e6:5.2f} M segments/s")


if __name__ == "__main__":
    main()
