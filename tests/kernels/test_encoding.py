import math

import pytest
import torch
from oracles.encoding_torch import positional_points

from vdnif_addon.errors import VDNIFError
from vdnif_addon.kernels import encoder as kernel
from vdnif_addon.model import encoding
from vdnif_addon.model.encoding import HashGrid, SegmentEncoder

PRIMES = (1, 2654435761, 805459861)


def reference_row(vertex, res, log2_table_size):
    """Row of a vertex within its level, written out as instant-ngp does it (uint32 arithmetic)."""
    if (res + 1) ** 3 <= 2**log2_table_size:
        return vertex[0] + vertex[1] * (res + 1) + vertex[2] * (res + 1) ** 2
    h = 0
    for coordinate, prime in zip(vertex, PRIMES):
        h ^= (coordinate * prime) % 2**32
    return h % 2**log2_table_size


def reference(grid, log2_table_size, points, out_weights):
    """Brute force, a point, level and corner at a time: (N, L*Fd) features, d(sum out*w)/dtable
    (the table is row-major, (rows, Fd))."""
    table = grid.table.detach().double()
    features = torch.zeros(len(points), grid.output_dim, dtype=torch.float64)
    grad = torch.zeros_like(table)
    for n, point in enumerate(points.tolist()):
        for level, res in enumerate(grid.resolutions):
            pos = [min(max(v, 0.0), 1.0) * res for v in point]
            cell = [min(math.floor(p), res - 1) for p in pos]
            frac = [p - c for p, c in zip(pos, cell)]
            for corner in range(8):
                bits = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
                vertex = [c + b for c, b in zip(cell, bits)]
                row = grid.level_offsets[level] + reference_row(vertex, res, log2_table_size)
                weight = math.prod(f if b else 1.0 - f for f, b in zip(frac, bits))
                for channel in range(grid.feature_dim):
                    column = level * grid.feature_dim + channel
                    features[n, column] += weight * table[row, channel]
                    grad[row, channel] += weight * out_weights[n, column].item()
    return features, grad


def special_points(resolution):
    """Grid vertices, the cube's corners and faces, and points just outside."""
    k = torch.tensor(
        [
            [0, 0, 0],
            [resolution, resolution, resolution],
            [3, 5, resolution],
            [1, resolution - 1, 2],
        ]
    )
    return torch.cat(
        [
            k.float() / resolution,
            torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 1.0], [0.5, 1.0, 0.25]]),
            torch.tensor(
                [[-1e-3, 0.5, 1.0 + 1e-3], [1.5, -0.2, 0.3], [1.0 + 1e-7, 1.0, 1.0 - 1e-7]]
            ),
        ]
    )


@pytest.mark.parametrize(
    "levels, base, growth, log2_size, feature_dim, expect_dense",
    [
        (2, 4, 1.5, 12, 2, 2),  # dense only
        (2, 20, 2.0, 10, 3, 0),  # hashed only
        (3, 6, 2.0, 12, 2, 2),  # dense levels, then a hashed one
    ],
)
def test_hash_grid_matches_brute_force_values_and_gradients(
    levels, base, growth, log2_size, feature_dim, expect_dense
):
    torch.manual_seed(0)
    grid = HashGrid(levels, base, growth, log2_size, feature_dim)
    assert grid.dense_levels == expect_dense
    with torch.no_grad():
        grid.table.uniform_(-1.0, 1.0)  # distinct values, so a wrong row cannot hide
    points = torch.cat([torch.rand(150, 3) * 1.1 - 0.05, special_points(grid.resolutions[0])])
    out_weights = torch.randn(len(points), grid.output_dim)

    features = grid(points)
    (features * out_weights).sum().backward()
    expected, expected_grad = reference(grid, log2_size, points, out_weights)

    assert features.shape == (len(points), levels * feature_dim)
    torch.testing.assert_close(features.double(), expected, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(grid.table.grad.double(), expected_grad, rtol=1e-5, atol=1e-5)


def test_vertices_and_cube_corners_read_their_own_table_rows():
    grid = HashGrid(2, 16, 2.0, 12, 3)  # level 0 dense (17^3 <= 4096), level 1 hashed
    with torch.no_grad():
        grid.table.copy_(torch.arange(grid.table.numel(), dtype=torch.float32).view_as(grid.table))
    for vertex in ([0, 0, 0], [16, 16, 16], [3, 16, 7], [16, 0, 9]):
        features = grid(torch.tensor([vertex], dtype=torch.float32) / 16).view(2, 3)
        for level, res in enumerate(grid.resolutions):
            scaled = [v * res // 16 for v in vertex]
            row = grid.level_offsets[level] + reference_row(scaled, res, 12)
            assert features[level].tolist() == grid.table[row].tolist()


@pytest.mark.parametrize("segments", [32, 49])
def test_launches_split_at_the_int32_limit_give_the_same_features_and_gradient(
    monkeypatch, segments
):
    """Batches beyond 2^31 output floats are encoded in several launches (a launch counts its
    end points in int32); a tiny limit splits this batch into launches of ``segments``, whose
    blocks fall where one launch's do (32: two CPU blocks of 16 end points) or elsewhere (49).
    The backward scatters end point by end point, so both give one launch's features and
    gradient bit for bit."""
    torch.manual_seed(1)
    encoder = SegmentEncoder(HashGrid(2, 8, 2.0, 10, 2), pe_bands=1)
    p0, p1 = torch.rand(2, 1000, 3)
    weights = torch.randn(1000, encoder.output_dim)
    (encoder(p0, p1) * weights).sum().backward()
    whole, whole_grad = encoder(p0, p1).detach(), encoder.grid.table.grad.clone()
    encoder.grid.table.grad = None
    width = encoder.output_dim  # 24 floats a segment
    monkeypatch.setattr(kernel, "MAX_LAUNCH_FLOATS", segments * width + width - 1)
    launched = []
    run = kernel.launches.run
    monkeypatch.setattr(kernel.launches, "run", lambda kernel_, device, stream, workers, jobs: (
        launched.append(len(jobs)), run(kernel_, device, stream, workers, jobs)))
    pieces = encoder(p0, p1)
    (pieces * weights).sum().backward()
    assert launched == [-(-1000 // segments)] * 2
    assert torch.equal(pieces, whole)
    assert torch.equal(encoder.grid.table.grad, whole_grad)


@pytest.mark.parametrize("form", ["paper", "pi"])
def test_gamma_points_follow_the_formula(form):
    """A dense grid whose vertex features are the vertex positions interpolates every point to
    itself, so the encoder's features are its gamma points: x, then (sin(2^k s x) + 1) / 2 and
    (cos(2^k s x) + 1) / 2 per band, end point by end point. The angle 2^k s x is a float32
    product (as torch formed it); its sin and cos are taken here in float64."""
    grid = HashGrid(levels=1, base_resolution=16, growth=1.0, log2_table_size=13, feature_dim=3)
    assert grid.dense_levels == 1
    vertices = torch.stack(torch.meshgrid(*[torch.arange(17.0)] * 3, indexing="ij"), -1)
    with torch.no_grad():  # row x + 17 y + 289 z holds (x, y, z) / 16
        grid.table.copy_(vertices.permute(2, 1, 0, 3).reshape(-1, 3) / 16)
    encoder = SegmentEncoder(grid, pe_bands=3, pe_form=form)
    p0, p1 = torch.rand(2, 200, 3)
    expected = []
    for x in (p0, p1):
        expected.append(x.double())
        for k in range(3):
            angle = (x * torch.tensor(2**k * encoding.PE_SCALES[form])).double()
            expected += [(angle.sin() + 1) / 2, (angle.cos() + 1) / 2]
    features = encoder(p0, p1).double()
    # interpolating the linear table rounds to within a few float32 units of 1
    torch.testing.assert_close(features, torch.cat(expected, 1), rtol=0, atol=3e-7)
    assert features.min() >= 0 and features.max() <= 1


def test_segment_encoder_concatenates_encoded_points_in_documented_order():
    torch.manual_seed(2)
    grid = HashGrid(2, 8, 2.0, 10, 3)
    encoder = SegmentEncoder(grid, pe_bands=2, pe_form="pi")
    p0, p1 = torch.rand(2, 11, 3)
    out = encoder(p0, p1)
    assert out.shape == (11, 2 * 5 * 2 * 3) == (11, encoder.output_dim)
    per_point = [
        grid(positional_points(p, 2, math.pi, correctly_rounded=True).reshape(-1, 3)).reshape(
            11, -1
        )
        for p in (p0, p1)
    ]
    assert torch.equal(out, torch.cat(per_point, 1))


def test_zero_bands_is_the_plain_grid_encoding():
    grid = HashGrid(2, 8, 2.0, 10, 3)
    p0, p1 = torch.rand(2, 5, 3)
    torch.testing.assert_close(SegmentEncoder(grid, 0)(p0, p1), torch.cat([grid(p0), grid(p1)], 1))


def test_table_initialisation_is_small_uniform():
    table = HashGrid().table
    assert table.shape == (2 * 2**16, 3) and table.is_contiguous()  # row-major
    assert table.abs().max() <= 1e-4 and table.std() > 1e-5


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"levels": 0}, "levels"),
        ({"base_resolution": 2.5}, "base_resolution"),
        ({"growth": 0.5}, "growth"),
        ({"log2_table_size": 40}, "log2_table_size"),
        ({"feature_dim": True}, "feature_dim"),
        ({"levels": 20, "base_resolution": 64}, "resolution"),
        ({"levels": 64, "base_resolution": 1024, "growth": 1.0, "log2_table_size": 24},
         "too large"),
    ],
)
def test_bad_grid_settings_name_the_setting(kwargs, word):
    with pytest.raises(VDNIFError, match=word):
        HashGrid(**kwargs)


def test_bad_encoder_settings_name_the_setting():
    with pytest.raises(VDNIFError, match="pe_form"):
        SegmentEncoder(HashGrid(1, 4, 1.0, 8, 1), 3, "peps")
    with pytest.raises(VDNIFError, match="pe_bands"):
        SegmentEncoder(HashGrid(1, 4, 1.0, 8, 1), -1)
