"""Input encoding psi(x) = phi(gamma(x)): sinusoidal points looked up in a multi-level hash grid.

DESIGN.md section 8 and the paper's Eq. (1). ``gamma`` expands a rest-space point into
``1 + 2F`` points in [0,1]^3, ``HashGrid`` (phi) interpolates learned features at each, and
``SegmentEncoder`` encodes both end points of a segment with one shared grid.

These modules own the table parameter, its level layout and the validation; the computation
is one Warp kernel (``kernels/encoder.py``) for the forward and one for the table gradient.
The table is row-major, ``(rows, Fd)``: a corner's features are one contiguous read.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import nn

from ..errors import VDNIFError
from ..kernels import encoder as kernel
from ..settings import PE_SCALES, check_encoding_settings, check_grid_settings, level_resolutions

if TYPE_CHECKING:
    from jaxtyping import Float

HASH_PRIMES = (1, 2654435761, 805459861)
"""instant-ngp's per-axis hash primes (x, y, z)."""


def readable_vertices(resolution: int, occupied_voxels: int, voxels_across: int) -> int:
    """At most how many vertices of a level ``resolution`` cells across can be read at points
    of ``occupied_voxels`` voxels, on a voxel grid ``voxels_across`` voxels across the unit
    cube (``VoxelGrid.normalize``). A voxel spans ``s = resolution / voxels_across`` of the
    level's cells along an axis; its points lie in at most ``floor(s) + 2`` of them, which
    have at most ``floor(s) + 3`` vertices."""
    per_axis = resolution // voxels_across + 3
    return min((resolution + 1) ** 3, occupied_voxels * per_axis**3)


def scene_log2_table_size(log2_table_size: int, levels: int, base_resolution: int,
                          growth: float, occupied_voxels: int, voxels_across: int) -> int:
    """The table size 2**T of a grid sized to its scene: the smallest power of two that holds
    every vertex its finest level can read there (``readable_vertices``), at most the
    setting's 2**``log2_table_size``. A scene that reads more vertices than that shares rows
    as before; one that reads fewer would leave the rest of a full table unread."""
    finest = level_resolutions(levels, base_resolution, growth)[-1]
    vertices = readable_vertices(finest, occupied_voxels, voxels_across)
    return max(1, min(log2_table_size, (vertices - 1).bit_length()))


def full_precision(points: Float[torch.Tensor, "*batch"], name: str
                   ) -> Float[torch.Tensor, "*batch"]:
    """``points`` as float32, refusing floats of fewer bits: a normalized position rounded to
    bfloat16 moves by up to 2**-9 of the grid (a quarter cell of a 128-cell level), to
    float16 by up to 2**-12, which changes the looked-up features. ``torch.autocast`` leaves
    the encoder in float32 (only the MLP runs in reduced precision), so positions need never
    be converted."""
    if points.is_floating_point() and torch.finfo(points.dtype).bits < 32:
        raise VDNIFError(
            f"{name} are {points.dtype}: positions must be float32 or float64, since reduced "
            f"precision rounds them within the hash grid's cells (autocast keeps them float32)"
        )
    return points.to(torch.float32)


def _points(points: Float[torch.Tensor, "N 3"], name: str) -> Float[torch.Tensor, "N 3"]:
    """(N, 3) float32, contiguous, as the kernels read positions."""
    if points.dim() != 2 or points.shape[1] != 3:
        raise VDNIFError(f"{name} must have shape (N, 3), got {tuple(points.shape)}")
    return full_precision(points, name).contiguous()


def feature_dtype(device: torch.device) -> torch.dtype:
    """The dtype the features are handed on in: bfloat16 under bfloat16 autocast on
    ``device``'s type, whose layers read them rounded so (the kernel rounds them as torch's
    conversion would, and reads their gradient as it comes, without two more passes over the
    batch's features), else float32. The lookup itself stays float32."""
    kind = device.type
    if torch.is_autocast_enabled(kind) and torch.get_autocast_dtype(kind) == torch.bfloat16:
        return torch.bfloat16
    return torch.float32


class _Encode(torch.autograd.Function):
    """The kernel's features as a function of the table: (N, C) in ``dtype``; backward
    scatter-adds into the table gradient (one kernel launch); positions get no gradient."""

    @staticmethod
    def forward(ctx: Any, table: Float[torch.Tensor, "rows Fd"], p0: Float[torch.Tensor, "N 3"],
                p1: Float[torch.Tensor, "N 3"] | None, encoding: kernel.Encoding,
                dtype: torch.dtype) -> Float[torch.Tensor, "N C"]:
        ctx.save_for_backward(p0, p1)
        ctx.encoding, ctx.rows = encoding, table.shape[0]
        return kernel.encode(encoding, table, p0, p1, dtype)

    @staticmethod
    def backward(ctx: Any, grad: Float[torch.Tensor, "N C"]
                 ) -> tuple[Float[torch.Tensor, "rows Fd"], None, None, None, None]:
        p0, p1 = ctx.saved_tensors
        return (kernel.encode_backward(ctx.encoding, ctx.rows, p0, p1, grad),
                None, None, None, None)


def _encode(table: Float[torch.Tensor, "rows Fd"], p0: Float[torch.Tensor, "N 3"],
            p1: Float[torch.Tensor, "N 3"] | None, encoding: kernel.Encoding
            ) -> Float[torch.Tensor, "N C"]:
    """Through autograd when the table's gradient is wanted, else the bare launch, the
    features in ``feature_dtype``. The launch reads raw pointers past Warp's own device
    checks, so a table and points on two devices are refused here (on a GPU they would be an
    illegal memory access)."""
    for points in (p0, p1):
        if points is not None and points.device != table.device:
            raise VDNIFError(f"the hash grid's table is on {table.device} but the points are "
                             f"on {points.device}: put the network and its inputs on one "
                             "device")
    dtype = feature_dtype(table.device)
    if torch.is_grad_enabled() and table.requires_grad:
        return _Encode.apply(table, p0, p1, encoding, dtype)
    return kernel.encode(encoding, table.detach(), p0, p1, dtype)


class HashGrid(nn.Module):
    """Multi-resolution hash grid (instant-ngp) with trilinear interpolation: (N,3) -> (N, L*Fd).

    Level ``l`` has ``floor(N_min * b**l)`` cells per axis. A level whose ``(res+1)**3``
    vertices fit in the ``2**T`` table is indexed densely (``x + y*(res+1) + z*(res+1)**2``),
    otherwise through the spatial hash ``(x*1 ^ y*2654435761 ^ z*805459861) mod 2**T`` taken in
    wrapping uint32 arithmetic, as instant-ngp does. Points are clamped to [0,1] (NaN read as
    0); a point at exactly 1 lies in the last cell, weight 1 on its far vertex. Corner
    ``4i + 2j + k`` of a cell is vertex ``cell + (i, j, k)``.

    ``table`` (rows, Fd): hashed levels first, each at a multiple of 2**T, then the dense
    ones; ``level_offsets[l]`` is level l's first row.
    """

    def __init__(
        self,
        levels: int = 2,
        base_resolution: int = 64,
        growth: float = 2.0,
        log2_table_size: int = 16,
        feature_dim: int = 3,
    ) -> None:
        super().__init__()
        check_grid_settings(levels, base_resolution, growth, log2_table_size, feature_dim)
        self.levels = levels
        self.base_resolution = base_resolution
        self.growth = growth
        self.log2_table_size = log2_table_size
        self.feature_dim = feature_dim
        self.resolutions = level_resolutions(levels, base_resolution, growth)
        table_size = 2**log2_table_size
        hashed = [(res + 1) ** 3 > table_size for res in self.resolutions]
        self.dense_levels = hashed.count(False)  # resolutions grow: the dense levels lead

        # Hashed levels come first in the table, at multiples of 2**T (instant-ngp's layout,
        # kept so that model files of every version share it).
        order = sorted(range(levels), key=lambda level: not hashed[level])
        sizes = [
            table_size if hashed[level] else (self.resolutions[level] + 1) ** 3 for level in order
        ]
        starts = [sum(sizes[:i]) for i in range(levels)]
        self.level_offsets = [starts[order.index(level)] for level in range(levels)]
        # Drawn feature-major and stored row-major: the same initial table for a seed as the
        # feature-major layout of model format 1 had.
        initial = torch.empty(feature_dim, sum(sizes)).uniform_(-1e-4, 1e-4)
        self.table = nn.Parameter(initial.t().contiguous())

        # What the kernel reads per level (kernels.encoder.LEVEL_FIELDS): resolution, first
        # row, y and z multipliers (hash primes or the dense strides) as int32 bit patterns.
        fields = []
        for level, res in enumerate(self.resolutions):
            y, z = HASH_PRIMES[1:] if hashed[level] else (res + 1, (res + 1) ** 2)
            fields += [res, self.level_offsets[level], y, z]
        bits = np.array(fields, dtype=np.uint32).view(np.int32)
        self.register_buffer("_levels", torch.from_numpy(bits.copy()), persistent=False)

    @property
    def output_dim(self) -> int:
        return self.levels * self.feature_dim

    def encoding(self, pe_bands: int = 0, pe_scale: float = 1.0) -> kernel.Encoding:
        """The launch description of this grid with ``pe_bands`` gamma bands."""
        return kernel.Encoding(self._levels, self.dense_levels, 2**self.log2_table_size - 1,
                        self.feature_dim, pe_bands, pe_scale)

    def forward(self, points: Float[torch.Tensor, "N 3"]) -> Float[torch.Tensor, "N L*Fd"]:
        """points: (N, 3) float32 or float64 in [0,1] (clamped) -> features (N, L*Fd),
        level-major, float32 (bfloat16 under bfloat16 autocast: ``feature_dtype``)."""
        return _encode(self.table, _points(points, "hash grid points"), None, self.encoding())


class SegmentEncoder(nn.Module):
    """psi of both segment end points through one shared hash grid, concatenated.

    gamma(x) = x, then per band k < F the points ``(sin(2^k s x) + 1) / 2`` and
    ``(cos(2^k s x) + 1) / 2`` (s = 1 in the paper's form, pi in PEPS's), each in [0,1]^3.
    """

    def __init__(self, grid: HashGrid, pe_bands: int = 3, pe_form: str = "paper") -> None:
        super().__init__()
        check_encoding_settings(pe_bands, pe_form)
        self.grid = grid
        self.pe_bands = pe_bands
        self.pe_scale = PE_SCALES[pe_form]

    @property
    def output_dim(self) -> int:
        return 2 * (1 + 2 * self.pe_bands) * self.grid.output_dim

    def forward(self, p0: Float[torch.Tensor, "N 3"], p1: Float[torch.Tensor, "N 3"]
                ) -> Float[torch.Tensor, "N 2*(1+2*F)*L*Fd"]:
        """p0, p1: (N, 3) normalized rest coordinates -> (N, 2*(1+2F)*L*Fd) float32
        (bfloat16 under bfloat16 autocast: ``feature_dtype``).

        Feature order: end point, gamma point, level, feature. Positions stay float32 under
        autocast (``full_precision``); the features have no gradient to them.
        """
        p0 = _points(p0, "segment end points")
        p1 = _points(p1, "segment end points")
        if p0.shape != p1.shape:
            raise VDNIFError(
                f"segment end points differ in shape: {tuple(p0.shape)} and {tuple(p1.shape)}"
            )
        encoding = self.grid.encoding(self.pe_bands, self.pe_scale)
        return _encode(self.grid.table, p0, p1, encoding)
