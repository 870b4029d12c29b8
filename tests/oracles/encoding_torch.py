"""The torch encoder the Warp kernel replaced (``vdnif_addon/kernels/encoder.py``), kept as
the test oracle: ``HashGrid`` and ``SegmentEncoder`` exactly as they ran before the kernel,
with the table feature-major ``(Fd, rows)`` as it was then.

``from_product`` builds the oracle of a product ``HashGrid`` / ``SegmentEncoder`` with the same
table (the product stores it row-major, ``(rows, Fd)``).

One addition to the old code: ``correctly_rounded=True`` takes gamma's sin and cos in float64
and rounds them to float32 (torch's float32 sin/cos, SLEEF, may be one unit in the last place
off), so that a kernel computing correctly rounded values can be compared exactly.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from vdnif_addon.model.encoding import HASH_PRIMES, full_precision
from vdnif_addon.settings import PE_SCALES, check_encoding_settings, check_grid_settings


class _Interpolate(torch.autograd.Function):
    """``sum_c weights[c] * table[:, rows[c]]``: table (Fd, R), rows and weights (8, M) -> (Fd, M).

    Written out so the backward is one product and one scatter-add; autograd's generic
    backward of the gather-multiply-sum chain costs about three times as much on CPU.
    """

    @staticmethod
    def forward(
        ctx, table: torch.Tensor, rows: torch.Tensor, weights: torch.Tensor
    ) -> torch.Tensor:
        index = rows.view(1, -1).expand(table.shape[0], -1)  # one gather serves every channel
        ctx.save_for_backward(index, weights)
        ctx.table_rows = table.shape[1]
        return table.gather(1, index).view((table.shape[0],) + weights.shape).mul_(weights).sum(1)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None, None]:
        index, weights = ctx.saved_tensors
        contribution = (grad[:, None] * weights).view(grad.shape[0], -1)
        return (
            grad.new_zeros(grad.shape[0], ctx.table_rows).scatter_add_(1, index, contribution),
            None,
            None,
        )


class HashGrid(nn.Module):
    """Multi-resolution hash grid (instant-ngp) with trilinear interpolation: (N,3) -> (N, L*Fd).

    Level ``l`` has ``floor(N_min * b**l)`` cells per axis. A level whose ``(res+1)**3``
    vertices fit in the ``2**T`` table is indexed densely (``x + y*(res+1) + z*(res+1)**2``),
    otherwise through the spatial hash ``(x*1 ^ y*2654435761 ^ z*805459861) mod 2**T``. The
    hash products are taken in int64 (coordinates < 2**17, so no overflow) and masked to T
    bits, which equals instant-ngp's wrapping uint32 product reduced mod 2**T (T <= 32).
    """

    chunk_points = 2**15
    """Points per block in ``features``: keeps the (8, L, block) temporaries in cache."""

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
        self.feature_dim = feature_dim
        self.resolutions = [math.floor(base_resolution * growth**level) for level in range(levels)]
        table_size = 2**log2_table_size
        hashed = [(res + 1) ** 3 > table_size for res in self.resolutions]
        self.dense_levels = hashed.count(
            False
        )  # resolutions grow, so the dense levels are a prefix

        # Hashed levels come first in the table, at multiples of 2**T: adding such an offset
        # commutes with XOR-ing T-bit terms, so each level's offset is added to its x terms only.
        order = sorted(range(levels), key=lambda level: not hashed[level])
        sizes = [
            table_size if hashed[level] else (self.resolutions[level] + 1) ** 3 for level in order
        ]
        starts = [sum(sizes[:i]) for i in range(levels)]
        self.level_offsets = [starts[order.index(level)] for level in range(levels)]
        multipliers = [
            HASH_PRIMES if hashed[level] else (1, res + 1, (res + 1) ** 2)
            for level, res in enumerate(self.resolutions)
        ]

        self.table = nn.Parameter(torch.empty(feature_dim, sum(sizes)).uniform_(-1e-4, 1e-4))
        res = torch.tensor(self.resolutions, dtype=torch.float32).view(1, levels, 1)
        self.register_buffer("_res", res, persistent=False)
        self.register_buffer("_last_cell", res - 1, persistent=False)
        self.register_buffer(
            "_mult", torch.tensor(multipliers).t().reshape(3, levels, 1), persistent=False
        )
        self.register_buffer("_mask", torch.tensor(table_size - 1), persistent=False)
        self.register_buffer(
            "_offsets", torch.tensor(self.level_offsets).view(levels, 1), persistent=False
        )

    @property
    def output_dim(self) -> int:
        return self.levels * self.feature_dim

    def corners(self, coords: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Table rows and trilinear weights of each point's 8 cell corners at every level.

        coords: (3, P) float32, coordinate-major, in [0,1] (clamped, NaN read as 0: 0, 1 and
        points outside are safe; a point at exactly 1 lies in the last cell, weight 1 on its
        far vertex).
        Returns rows (8, L, P) int64 into ``table`` and weights (8, L, P) float32; corner
        ``4i + 2j + k`` is vertex ``cell + (i, j, k)``.
        """
        pos = torch.nan_to_num(coords).clamp_(0.0, 1.0)[:, None, :] * self._res  # (3, L, P)
        cell = torch.minimum(pos.floor(), self._last_cell)
        frac = pos - cell
        low = cell.long() * self._mult
        terms = torch.stack((low, low + self._mult), 1).bitwise_and_(
            self._mask
        )  # (3, 2, L, P) per-axis terms
        terms[0] += self._offsets

        tx, ty, tz = terms[0, :, None, None], terms[1, None, :, None], terms[2, None, None, :]
        rows = torch.empty((2, 2, 2) + pos.shape[1:], dtype=torch.int64, device=coords.device)
        d = self.dense_levels
        torch.add(tx[..., :d, :] + ty[..., :d, :], tz[..., :d, :], out=rows[..., :d, :])
        torch.bitwise_xor(tx[..., d:, :] ^ ty[..., d:, :], tz[..., d:, :], out=rows[..., d:, :])

        w = torch.stack((1.0 - frac, frac), 1)  # (3, 2, L, P)
        weights = w[0, :, None, None] * w[1, None, :, None] * w[2, None, None, :]
        return rows.view(8, *pos.shape[1:]), weights.view(8, *pos.shape[1:])

    def features(self, coords: torch.Tensor) -> torch.Tensor:
        """coords: (3, P) float32 in [0,1] -> interpolated features (Fd, L, P).

        Works through the points in blocks of ``chunk_points``: on CPU, cache-sized
        temporaries are worth several times the speed of one pass over a large batch.
        """
        blocks = [self._interpolate(block) for block in coords.split(self.chunk_points, 1)]
        return blocks[0] if len(blocks) == 1 else torch.cat(blocks, 2)

    def _interpolate(self, coords: torch.Tensor) -> torch.Tensor:
        rows, weights = self.corners(coords)
        values = _Interpolate.apply(self.table, rows.view(8, -1), weights.view(8, -1))
        return values.view(self.feature_dim, self.levels, coords.shape[1])

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """points: (N, 3) float32 or float64 in [0,1] (clamped) -> features (N, L*Fd),
        level-major."""
        coords = full_precision(points, "hash grid points").t().contiguous()
        return self.features(coords).transpose(0, 1).reshape(self.output_dim, points.shape[0]).t()


def _gamma(
    x: torch.Tensor, bands: int, scale: float, dim: int, correctly_rounded: bool = False
) -> torch.Tensor:
    """Elementwise gamma: the 1+2F variants of x stacked along a new axis ``dim``."""
    dim = dim % (x.dim() + 1)
    x = x.unsqueeze(dim)
    if bands == 0:
        return x
    shape = [1] * x.dim()
    shape[dim] = bands
    freqs = scale * 2.0 ** torch.arange(bands, dtype=x.dtype, device=x.device)
    angles = x * freqs.view(shape)
    if correctly_rounded:
        sin, cos = angles.double().sin().to(x.dtype), angles.double().cos().to(x.dtype)
    else:
        sin, cos = angles.sin(), angles.cos()
    waves = torch.stack((sin, cos), dim + 1).flatten(dim, dim + 1)
    return torch.cat((x, waves.add_(1.0).mul_(0.5)), dim)


def positional_points(
    x: torch.Tensor, bands: int, scale: float = 1.0, correctly_rounded: bool = False
) -> torch.Tensor:
    """gamma(x) as points: x (..., 3) -> (..., 1+2F, 3).

    Point 0 is x itself; points 1+2k and 2+2k are ``sin(2^k s x)`` and ``cos(2^k s x)``,
    remapped into [0,1]^3 by ``(v+1)/2``. ``scale`` s is 1 for the paper's form, pi for PEPS.
    """
    return _gamma(x, bands, scale, -2, correctly_rounded)


class SegmentEncoder(nn.Module):
    """psi of both segment end points through one shared hash grid, concatenated."""

    def __init__(
        self,
        grid: HashGrid,
        pe_bands: int = 3,
        pe_form: str = "paper",
        correctly_rounded: bool = False,
    ) -> None:
        super().__init__()
        check_encoding_settings(pe_bands, pe_form)
        self.grid = grid
        self.pe_bands = pe_bands
        self.pe_scale = PE_SCALES[pe_form]
        self.correctly_rounded = correctly_rounded

    @property
    def output_dim(self) -> int:
        return 2 * (1 + 2 * self.pe_bands) * self.grid.output_dim

    def forward(self, p0: torch.Tensor, p1: torch.Tensor) -> torch.Tensor:
        """p0, p1: (N, 3) normalized rest coordinates -> (N, 2*(1+2F)*L*Fd).

        Feature order: end point, gamma point, level, feature. The result is a transposed
        view of a feature-major (C, N) array, which ``nn.Linear`` consumes without a copy.
        """
        n = p0.shape[0]
        ends = [full_precision(p, "segment end points") for p in (p0, p1)]
        coords = torch.stack(ends).permute(2, 0, 1).contiguous()  # (3, 2, N)
        points = _gamma(
            coords, self.pe_bands, self.pe_scale, 2, self.correctly_rounded
        )  # (3, 2, 1+2F, N)
        features = self.grid.features(points.view(3, -1))  # (Fd, L, 2*(1+2F)*N)
        features = features.view(
            self.grid.feature_dim, self.grid.levels, 2, 1 + 2 * self.pe_bands, n
        ).permute(2, 3, 1, 0, 4)
        return features.reshape(self.output_dim, n).t()


def from_product(module: nn.Module, correctly_rounded: bool = False) -> nn.Module:
    """The oracle twin of a product ``encoding.HashGrid`` or ``encoding.SegmentEncoder``: the
    same layout and settings, a copy of its table (transposed to feature-major)."""
    product = getattr(module, "grid", module)
    grid = HashGrid(product.levels, product.base_resolution, product.growth,
                    product.log2_table_size, product.feature_dim)
    assert grid.level_offsets == product.level_offsets and grid.resolutions == product.resolutions
    with torch.no_grad():
        grid.table.copy_(product.table.detach().t())
    grid.to(product.table.device)
    if module is product:
        return grid
    form = next(name for name, scale in PE_SCALES.items() if scale == module.pe_scale)
    return SegmentEncoder(grid, module.pe_bands, form, correctly_rounded)
