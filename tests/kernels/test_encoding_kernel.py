"""The Warp encoder kernel against the torch encoder it replaced (``oracles.encoding_torch``):
features and table gradients, on random points, grid vertices, the cube's faces, points
outside it and NaN / infinite coordinates, for dense and hashed levels, several level counts,
table sizes, feature widths, band counts and both gamma forms; and the wrapper's gradient
against finite differences."""

import math

import numpy as np
import pytest
import torch
import warp as wp
from oracles import encoder_scalar
from oracles import encoding_torch as oracle

from vdnif_addon.errors import VDNIFError
from vdnif_addon.kernels import encoder as kernel
from vdnif_addon.model.encoding import HashGrid, SegmentEncoder

CONFIGS = [  # levels, base, growth, log2 table size, Fd, bands, form, dense levels expected
    pytest.param(2, 64, 2.0, 16, 3, 3, "paper", 0, id="paper-setting"),
    pytest.param(2, 4, 1.5, 12, 2, 0, "paper", 2, id="dense-only"),
    pytest.param(2, 20, 2.0, 10, 3, 1, "pi", 0, id="hashed-only"),
    pytest.param(3, 6, 2.0, 12, 2, 2, "pi", 2, id="dense-then-hashed"),
    pytest.param(4, 3, 1.7, 9, 1, 3, "paper", 2, id="four-levels-Fd1"),
    pytest.param(1, 10, 2.0, 8, 4, 2, "pi", 0, id="one-level-Fd4"),
    pytest.param(2, 8, 2.0, 11, 5, 1, "paper", 1, id="Fd5-five-chunks"),
    pytest.param(2, 8, 1.3, 14, 6, 2, "pi", 2, id="Fd6-two-chunks"),
]


def points(resolution, count=300, seed=0):
    """Random points in and around the unit cube, grid vertices of the base level, the cube's
    corners and faces, points outside and non-finite coordinates."""
    generator = torch.Generator().manual_seed(seed)
    vertices = torch.randint(0, resolution + 1, (20, 3), generator=generator) / resolution
    special = torch.tensor(
        [
            [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 1.0], [0.5, 1.0, 0.25],
            [-1e-3, 0.5, 1.0 + 1e-3], [1.5, -0.2, 0.3], [1.0 + 1e-7, 1.0, 1.0 - 1e-7],
            [-7.0, 3.0, 40.0], [7e4, -2e5, 3e7], [float("nan"), 0.5, 0.5],
            [0.3, float("inf"), float("-inf")],
            [float("nan")] * 3,
        ]
    )
    random = torch.rand(count, 3, generator=generator) * 1.4 - 0.2
    return torch.cat([random, vertices, special])


def encoder_pair(levels, base, growth, log2_size, feature_dim, bands, form, seed=0):
    torch.manual_seed(seed)
    encoder = SegmentEncoder(HashGrid(levels, base, growth, log2_size, feature_dim), bands, form)
    with torch.no_grad():
        encoder.grid.table.uniform_(-1.0, 1.0)  # distinct values: a wrong row cannot hide
    return encoder, oracle.from_product(encoder, correctly_rounded=True)


def forward_and_gradient(encoder, p0, p1, weights):
    """Features (N, C) and d(sum weights * features) / d table, row-major (rows, Fd)."""
    encoder.zero_grad(set_to_none=True)
    features = encoder(p0, p1)
    (features * weights).sum().backward()
    grad = encoder.grid.table.grad
    return features.detach(), grad.t() if isinstance(encoder, oracle.SegmentEncoder) else grad


@pytest.mark.parametrize("levels, base, growth, log2_size, feature_dim, bands, form, dense",
                         CONFIGS)
def test_features_and_table_gradient_equal_the_torch_oracle(
    levels, base, growth, log2_size, feature_dim, bands, form, dense
):
    """To 1e-6 relative, with an absolute floor of 1e-6 of the largest magnitude (features sum
    8 signed products; where they cancel, their rounding is relative to the terms)."""
    encoder, reference = encoder_pair(levels, base, growth, log2_size, feature_dim, bands, form)
    assert encoder.grid.dense_levels == dense
    p0 = points(base)
    p1 = points(base, seed=1)
    weights = torch.randn(len(p0), encoder.output_dim)

    features, gradient = forward_and_gradient(encoder, p0, p1, weights)
    expected, expected_gradient = forward_and_gradient(reference, p0, p1, weights)

    assert features.shape == (len(p0), 2 * (1 + 2 * bands) * levels * feature_dim)
    assert torch.isfinite(features).all() and torch.isfinite(gradient).all()
    torch.testing.assert_close(features, expected, rtol=1e-6, atol=1e-6)  # |table| <= 1
    scale = expected_gradient.abs().max().item()
    torch.testing.assert_close(gradient, expected_gradient, rtol=1e-6, atol=1e-6 * scale)


@pytest.mark.parametrize("levels, base, growth, log2_size, feature_dim, bands, form, dense",
                         CONFIGS)
def test_blocks_equal_the_scalar_kernel_bit_for_bit(
    levels, base, growth, log2_size, feature_dim, bands, form, dense
):
    """The block encoder runs the scalar kernel's operations in its order, several end points
    at once: features and table gradients are the same bits, partial blocks, NaN and points
    outside the cube included."""
    encoder, _ = encoder_pair(levels, base, growth, log2_size, feature_dim, bands, form)
    table = encoder.grid.table.detach()
    enc = encoder.grid.encoding(encoder.pe_bands, encoder.pe_scale)
    p0, p1 = points(base), points(base, seed=1)
    weights = torch.randn(len(p0), encoder.output_dim)

    features = kernel.encode(enc, table, p0, p1)
    assert torch.equal(features, encoder_scalar.encode(enc, table, p0, p1))
    assert torch.equal(kernel.encode(enc, table, p0, None),
                       encoder_scalar.encode(enc, table, p0, None))
    assert torch.equal(kernel.encode_backward(enc, len(table), p0, p1, weights),
                       encoder_scalar.encode_backward(enc, len(table), p0, p1, weights))


@pytest.mark.parametrize("levels, base, growth, log2_size, feature_dim, bands, form, dense",
                         CONFIGS)
def test_bfloat16_features_are_the_float32_ones_rounded_by_torch(
    levels, base, growth, log2_size, feature_dim, bands, form, dense
):
    """Written in bfloat16, the features are torch's rounding of the float32 ones, and a
    bfloat16 output gradient scatters as its float32 values do: NaN, infinite and outside
    points, partial blocks and every chunk width included."""
    encoder, _ = encoder_pair(levels, base, growth, log2_size, feature_dim, bands, form)
    table = encoder.grid.table.detach()
    enc = encoder.grid.encoding(encoder.pe_bands, encoder.pe_scale)
    p0, p1 = points(base), points(base, seed=1)
    weights = torch.randn(len(p0), encoder.output_dim).to(torch.bfloat16)
    for second in (p1, None):
        full = kernel.encode(enc, table, p0, second)
        rounded = kernel.encode(enc, table, p0, second, torch.bfloat16)
        assert rounded.dtype == torch.bfloat16
        finite = full.isfinite()
        assert torch.equal(rounded[finite], full[finite].to(torch.bfloat16))
        assert torch.equal(rounded.isnan(), full.isnan())
    assert torch.equal(kernel.encode_backward(enc, len(table), p0, p1, weights),
                       kernel.encode_backward(enc, len(table), p0, p1, weights.float()))
    with pytest.raises(ValueError, match="float32 or bfloat16 features"):
        kernel.encode(enc, table, p0, p1, torch.float16)


def band_values(sine, cosine, bands):
    """Float32 sin and cos of bands 0 .. bands - 1 from band 0's float64 ones, by the double
    angle formulas as the kernels form them: (bands, 2, N) float32."""
    values = []
    for _ in range(bands):
        values.append(np.stack([sine, cosine]).astype(np.float32))
        sine, cosine = (sine * cosine) * 2.0, (cosine - sine) * (cosine + sine)
    return np.stack(values)


def test_band_sincos_is_libms_to_a_unit_and_rounds_as_it_to_float32():
    """The kernels' vectorized sin and cos of band 0 against numpy's (the C library's), on
    the float32 angles the kernels form (``x * s``, s = 1 and pi) within its reach: within
    one unit in the last place of float64, and every band's float32 value (F = 3, the
    default) the same as from the library's, on 2^20 angles, multiples of pi/2 and its
    edges included."""
    snippet = kernel.BAND_SINCOS + r"""
double sine, cosine;
band_sincos(((const double*)angles.data)[i], sine, cosine);
((double*)out.data)[2 * i] = sine;
((double*)out.data)[2 * i + 1] = cosine;
"""

    @wp.func_native(snippet)
    def band_sincos(i: int, angles: wp.array(dtype=wp.float64),
                    out: wp.array(dtype=wp.float64)): ...

    @wp.kernel(module="unique")
    def sincos_kernel(angles: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
        band_sincos(wp.tid(), angles, out)

    generator = np.random.default_rng(7)
    raw = np.concatenate([
        generator.uniform(-0.5, 1.5, 2**19), generator.uniform(-2e4, 2e4, 2**18),
        generator.uniform(-1.0, 1.0, 2**18) * 10.0 ** generator.uniform(-30, 0, 2**18),
        np.arange(-64, 65) * (np.pi / 4), [0.0, -0.0, 65536.0 / np.pi, 65536.0],
    ]).astype(np.float32)
    angles = np.concatenate([(raw * np.float32(scale)).astype(np.float64)
                             for scale in (1.0, np.pi)])
    angles = angles[np.abs(angles) <= 65536.0]
    out = wp.zeros(2 * len(angles), dtype=wp.float64, device="cpu")
    wp.launch(sincos_kernel, dim=len(angles),
              inputs=[wp.array(angles, dtype=wp.float64, device="cpu"), out], device="cpu")
    sine, cosine = out.numpy().reshape(-1, 2).T
    for value, exact in ((sine, np.sin(angles)), (cosine, np.cos(angles))):
        assert np.all(np.abs(value - exact) <= np.spacing(np.abs(exact)))
    assert np.array_equal(band_values(sine, cosine, 3),
                          band_values(np.sin(angles), np.cos(angles), 3))


def test_torch_float32_sin_moves_gamma_points_by_at_most_a_unit_in_the_last_place():
    """Against the oracle as it ran (torch's float32 sin/cos, SLEEF, up to one unit in the last
    place off): a gamma point moves by at most 2^-24 per coordinate, so a feature by at most
    3 * res * 2^-24 * (table range), res the finest level's cells per axis."""
    encoder, _ = encoder_pair(2, 64, 2.0, 16, 3, 3, "paper")
    sleef = oracle.from_product(encoder)
    p0, p1 = points(64), points(64, seed=1)
    with torch.no_grad():
        features, expected = encoder(p0, p1), sleef(p0, p1)
    bound = 3 * 128 * 2.0**-24 * 2.0
    assert (features - expected).abs().max() <= bound
    assert (features != expected).any(), "SLEEF no longer differs: tighten this test"


def test_gradient_matches_finite_differences():
    """Features are linear in the table, so a finite difference along any direction D is exact
    but for float32 rounding: sum(w * (f(T + D) - f(T))) = <d/dT sum(w * f), D> to 1e-5
    relative (float64 gradcheck does not apply: the kernels are float32 only)."""
    encoder, _ = encoder_pair(3, 6, 2.0, 12, 2, 2, "pi")
    p0, p1 = points(6), points(6, seed=1)
    weights = torch.randn(len(p0), encoder.output_dim)
    features, gradient = forward_and_gradient(encoder, p0, p1, weights)
    direction = torch.randn_like(gradient)
    with torch.no_grad():
        encoder.grid.table += direction
        moved = encoder(p0, p1)
    difference = (weights.double() * (moved.double() - features.double())).sum()
    predicted = (gradient.double() * direction.double()).sum()
    assert difference.item() == pytest.approx(predicted.item(), rel=1e-5)


def test_positions_get_no_gradient_and_the_table_gets_one():
    encoder, _ = encoder_pair(2, 8, 2.0, 10, 3, 1, "paper")
    p0 = torch.rand(50, 3, requires_grad=True)
    p1 = torch.rand(50, 3)
    encoder(p0, p1).sum().backward()
    assert p0.grad is None and encoder.grid.table.grad.abs().sum() > 0


def test_repeated_runs_are_identical_on_the_cpu():
    encoder, _ = encoder_pair(2, 64, 2.0, 16, 3, 3, "paper")
    p0, p1 = points(64), points(64, seed=1)
    weights = torch.randn(len(p0), encoder.output_dim)
    first = forward_and_gradient(encoder, p0, p1, weights)
    second = forward_and_gradient(encoder, p0, p1, weights)
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])


def test_float64_positions_are_read_as_float32_and_half_precision_is_refused():
    encoder, _ = encoder_pair(2, 8, 2.0, 10, 3, 2, "paper")
    p0, p1 = torch.rand(2, 20, 3, dtype=torch.float64)
    with torch.no_grad():
        assert torch.equal(encoder(p0, p1), encoder(p0.float(), p1.float()))
        with pytest.raises(VDNIFError, match="bfloat16"):
            encoder(p0.bfloat16(), p1.float())
        with pytest.raises(VDNIFError, match=r"shape \(N, 3\)"):
            encoder(p0[:, :2], p1[:, :2])
        with pytest.raises(VDNIFError, match="differ in shape"):
            encoder(p0, p1[:5])
        assert encoder(p0[:0], p1[:0]).shape == (0, encoder.output_dim)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_runs_the_same_kernels():
    """Same features as on the CPU (the GPU's libm sin/cos may round a few points differently:
    the SLEEF bound above), and the same table gradient up to the order of atomic additions."""
    encoder, _ = encoder_pair(2, 64, 2.0, 16, 3, 3, "paper")
    p0, p1 = points(64), points(64, seed=1)
    weights = torch.randn(len(p0), encoder.output_dim)
    features, gradient = forward_and_gradient(encoder, p0, p1, weights)
    # ``Module.cuda`` moves a parameter's gradient in place: keep the CPU copy apart.
    gradient = gradient.clone()
    encoder.cuda()
    cuda_features, cuda_gradient = forward_and_gradient(
        encoder, p0.cuda(), p1.cuda(), weights.cuda()
    )
    assert (cuda_features.cpu() - features).abs().max() <= 3 * 128 * 2.0**-24 * 2.0
    scale = gradient.abs().max().item()
    torch.testing.assert_close(cuda_gradient.cpu(), gradient, rtol=1e-4, atol=1e-4 * scale)


def test_the_encoders_cuda_source_compiles_without_a_gpu(tmp_path):
    """The encoder's body is C++ that only a GPU runs in its CUDA form (a block of one end
    point, no vectorizing pragma): Warp's NVRTC compiles it to PTX for an old and a new GPU
    here, so a CPU-only machine catches what would break the CUDA path."""
    import warp as wp
    from warp._src.context import get_module

    from vdnif_addon.kernels import runtime

    runtime.load(kernel.WARP_MODULE, "cpu")
    module = get_module(kernel.WARP_MODULE)
    try:
        built = wp.compile_aot_module(module, arch=[75, 90], module_dir=tmp_path, use_ptx=True)
    except RuntimeError as error:       # a Warp build without NVRTC
        pytest.skip(f"no CUDA compiler in this Warp: {error}")
    ptx = [path.read_text(errors="replace") for path in built]
    assert len(ptx) == 2
    for text in ptx:
        assert "_encode_" in text and "_encode_backward_" in text
    source = next(tmp_path.glob("*.cu")).read_text()
    assert "constexpr int BLOCK = 1;" in source and "clang loop vectorize" in source


def test_a_level_of_the_paper_setting_reads_the_hash_of_its_vertex():
    """Spot check of the hash against instant-ngp's formula written out in Python integers."""
    grid = HashGrid(2, 64, 2.0, 16, 3)
    with torch.no_grad():
        grid.table.copy_(torch.arange(grid.table.numel(), dtype=torch.float32).view_as(grid.table))
    vertex = (37, 5, 64)
    features = grid(torch.tensor([vertex], dtype=torch.float32) / 64).view(2, 3)
    for level, res in enumerate(grid.resolutions):
        x, y, z = (v * res // 64 for v in vertex)
        row = grid.level_offsets[level] + (
            (x ^ (y * 2654435761) ^ (z * 805459861)) % 2**32 % 2**16
        )
        assert features[level].tolist() == grid.table[row].tolist()
    assert math.prod(grid.table.shape) == 2 * 2**16 * 3


def test_a_table_and_points_on_two_devices_are_refused_before_the_launch():
    """The launch reads raw pointers past Warp's device checks: on a GPU a table on one
    device and points on another would be an illegal memory access. (The "meta" device
    stands in for the second device on a machine without CUDA.)"""
    grid = HashGrid(levels=2, base_resolution=4, log2_table_size=8, feature_dim=2)
    points = torch.rand(10, 3, device="meta")
    with pytest.raises(VDNIFError, match="table is on cpu but the points are on meta"):
        grid(points)
