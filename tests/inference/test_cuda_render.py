"""The neural render on CUDA with the real network (the Warp encoder and torch's MLP inside
the wave loop), against the same network on the CPU; skipped without CUDA. Every segment is
made a hit (thresholds near 0), so an untrained network decides nothing by a hair and each
ray's hit lies on its first segment at the network's fraction: the devices must agree to
float32 rounding."""

import copy

import numpy as np
import pytest
import torch
from test_render import bent_ball

from vdnif_addon.inference import secondary
from vdnif_addon.inference.neural_render import neural_passes
from vdnif_addon.kernels import runtime
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.model.metadata import Thresholds
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import Heads, NetworkConfig
from vdnif_addon.tracing import rays

CUDA = torch.cuda.is_available() and runtime.cuda_device_count() > 0
SETTINGS = {"levels": 2, "base_resolution": 16, "log2_table_size": 12, "width": 32, "depth": 2}


def view():
    """(mesh, grid, bent corners, an untrained network, rays (R, 3) of one orbit view)."""
    mesh, grid, bend = bent_ball(12)
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(**SETTINGS,
                                                heads=Heads(albedo=True, material_count=2)))
    network.thresholds = Thresholds(1e-6, 1e-6)
    network.eval()
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([-0.5, 0.4, 1]) /
                                          np.linalg.norm([-0.5, 0.4, 1]), 48, 40)
    return mesh, grid, bend, network, origins, directions


def render_both(device, origins=None, directions=None, **options):
    """(CPU passes, ``device`` passes, its stats) of the bent ball, of the view's rays or
    of ``origins``, ``directions``."""
    mesh, grid, bend, network, view_origins, view_directions = view()
    if origins is None:
        origins, directions = view_origins, view_directions
    table = mesh.albedo_table()
    cpu, _ = neural_passes(network, grid, table, DeviceCells(grid, corners=bend), origins,
                           directions, **options)
    other, stats = neural_passes(copy.deepcopy(network).to(device), grid, table,
                                 DeviceCells(grid, str(torch.device(device)), corners=bend),
                                 origins, directions, device=device, **options)
    return cpu, other, stats


def assert_alike(cpu, other):
    assert cpu.hit.sum() > 200
    np.testing.assert_array_equal(other.hit, cpu.hit)
    np.testing.assert_allclose(other.distance, cpu.distance, rtol=0, atol=1e-5)
    np.testing.assert_allclose(other.normal, cpu.normal, rtol=0, atol=1e-4)
    np.testing.assert_allclose(other.albedo, cpu.albedo, rtol=0, atol=1e-4)


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
@pytest.mark.parametrize("cap", [None, 500])
def test_the_real_network_renders_alike_on_cuda_and_the_cpu(cap):
    options = {} if cap is None else {"max_wave_segments": cap}
    cpu, gpu, stats = render_both("cuda:0", **options)
    assert_alike(cpu, gpu)
    assert stats["truncated"] == 0


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_secondary_rays_render_alike_on_cuda_and_the_cpu():
    """Rays that leave the primary hits as the secondary passes cast them: each starts
    inside an occupied cell and is walked only to a reach of its own."""
    _, grid, _, _, origins, directions = view()
    primary, _, _ = render_both("cuda:0")
    point, normal = (np.repeat(value, 4, axis=0)
                     for value in secondary.secondary_starts(primary, origins, directions))
    rng = np.random.default_rng(0)
    leaving = secondary.cosine_directions(normal, rng.random((len(normal), 2)))
    start, along = secondary.leave_surface(point, normal, leaving, 0.25 * grid.voxel_size)
    reach = rng.uniform(0.2, 2.0, len(start)) * grid.voxel_size - along
    cpu, gpu, _ = render_both("cuda:0", start, leaving, max_distance=reach)
    assert_alike(cpu, gpu)


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_a_render_under_a_side_stream_reads_finished_passes():
    """Under ``torch.cuda.stream`` (a non-blocking stream) the passes read back are the
    finished ones."""
    with torch.cuda.stream(torch.cuda.Stream()):
        cpu, gpu, _ = render_both("cuda:0")
    assert_alike(cpu, gpu)
