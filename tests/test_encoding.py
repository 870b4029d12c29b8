import math

import pytest
import torch

from vdnif_addon import encoding
from vdnif_addon.encoding import HashGrid, SegmentEncoder, positional_points
from vdnif_addon.errors import VDNIFError

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
    """Brute force, a point, level and corner at a time: (N, L*Fd) features, d(sum out*w)/dtable."""
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
                    features[n, column] += weight * table[channel, row]
                    grad[channel, row] += weight * out_weights[n, column].item()
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
            assert features[level].tolist() == grid.table[:, row].tolist()


def test_blocked_evaluation_equals_one_pass(monkeypatch):
    torch.manual_seed(1)
    grid = HashGrid(2, 8, 2.0, 10, 2)
    points = torch.rand(1000, 3)
    whole = grid(points)
    monkeypatch.setattr(HashGrid, "chunk_points", 97)
    torch.testing.assert_close(
        grid(points), whole, rtol=1e-6, atol=1e-9
    )  # summation order may differ


def test_positional_points_formula():
    x = torch.rand(7, 3)
    for form, scale in (("paper", 1.0), ("pi", math.pi)):
        points = positional_points(x, 2, encoding.PE_SCALES[form])
        assert points.shape == (7, 5, 3)
        expected = [x]
        for k in range(2):
            expected += [
                (torch.sin(2**k * scale * x) + 1) / 2,
                (torch.cos(2**k * scale * x) + 1) / 2,
            ]
        torch.testing.assert_close(points, torch.stack(expected, 1))
        assert points.min() >= 0 and points.max() <= 1
    assert torch.equal(positional_points(x, 0), x[:, None])


def test_segment_encoder_concatenates_encoded_points_in_documented_order():
    torch.manual_seed(2)
    grid = HashGrid(2, 8, 2.0, 10, 3)
    encoder = SegmentEncoder(grid, pe_bands=2, pe_form="pi")
    p0, p1 = torch.rand(2, 11, 3)
    out = encoder(p0, p1)
    assert out.shape == (11, 2 * 5 * 2 * 3) == (11, encoder.output_dim)
    per_point = [
        grid(positional_points(p, 2, math.pi).reshape(-1, 3)).reshape(11, -1) for p in (p0, p1)
    ]
    torch.testing.assert_close(out, torch.cat(per_point, 1))


def test_zero_bands_is_the_plain_grid_encoding():
    grid = HashGrid(2, 8, 2.0, 10, 3)
    p0, p1 = torch.rand(2, 5, 3)
    torch.testing.assert_close(SegmentEncoder(grid, 0)(p0, p1), torch.cat([grid(p0), grid(p1)], 1))


def test_table_initialisation_is_small_uniform():
    table = HashGrid().table
    assert table.shape == (3, 2 * 2**16)
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
