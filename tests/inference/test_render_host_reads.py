"""The render's reads of device values on the host (on CUDA each waits for the queued work):
with the lane's count read every ``waves_per_read`` waves, a frame's reads do not grow with
its waves, and the passes are those of a render that reads every wave. Checked on the CPU,
where the counter sees the calls a CUDA render would stall on (``host_reads``)."""

import numpy as np
import pytest
import torch
from host_reads import counting_host_reads
from test_render import RandomNetwork, bent_ball

from vdnif_addon.errors import VDNIFError
from vdnif_addon.inference import neural_render as render
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.model.network import IntersectionNetwork, NetworkConfig, Thresholds
from vdnif_addon.tracing import rays

PASSES = ("hit", "distance", "normal", "albedo", "material")


class DeviceRandomNetwork(RandomNetwork):
    """RandomNetwork, taking the render's request to leave its candidates on the device (it
    never reads them)."""

    def predict(self, p0, p1, rest_len, voxel_size, select_candidates=True):
        return super().predict(p0, p1, rest_len, voxel_size)


def small_network(occlusion=0.97, candidate=0.9):
    """A small untrained network with the normal and albedo fields read at the hit (the
    defaults), its thresholds at these quantiles of its occlusion on random segments."""
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(levels=2, base_resolution=8,
                                                log2_table_size=10, width=16, depth=2))
    assert set(network.point_fields()) == {"normal", "albedo"}
    p0, p1 = torch.rand(2, 2000, 3)
    with torch.no_grad():
        probability = torch.sigmoid(network(p0, p1)["occlusion"])
    network.thresholds = Thresholds(float(probability.quantile(occlusion)),
                                    float(probability.quantile(candidate)))
    return network


def view(side, ball):
    mesh, grid, bend = ball
    direction = np.array([0.3, -1, 0.2]) / np.linalg.norm([0.3, -1, 0.2])
    return rays.orbit_rays(bend.min(0), bend.max(0), direction, side, side)


def test_a_frames_host_reads_do_not_grow_with_its_waves():
    """One wave (k = 16 segments per ray) against eight or more (k = 1) and two view
    sizes: the same reads per frame when the count is read once per 12 waves, where a
    render that reads every wave reads more the more waves it takes."""
    ball = mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    network = small_network()
    counted = {}
    for side in (6, 12):
        origins, directions = view(side, ball)
        for schedule in ((16,), (1,)):
            for per_read in (1, 12):
                with counting_host_reads() as reads:
                    _, stats = render.neural_passes(
                        network, grid, mesh.albedo_table(), cells, origins, directions,
                        schedule=schedule, lanes=1, waves_per_read=per_read, wave_floor=0)
                waves = stats["waves"] if per_read == 1 else None
                counted[side, schedule, per_read] = len(reads), waves
    for side in (6, 12):
        assert counted[side, (16,), 1][1] == 1
        assert 8 <= counted[side, (1,), 1][1] <= 12
        # every wave reads: its segments, its candidates and its lane's count
        assert counted[side, (1,), 1][0] > counted[side, (16,), 1][0]
    constant = {reads for (_, _, per_read), (reads, _) in counted.items() if per_read == 12}
    assert len(constant) == 1, counted
    # the lane's count once, then the frame's totals, its five passes and its hits' cells
    assert constant.pop() <= 8


@pytest.mark.parametrize("albedo", [False, True])
@pytest.mark.parametrize("lanes, max_wave_segments", [(1, 1 << 22), (2, 300)])
def test_reading_every_few_waves_renders_the_same_passes(albedo, lanes, max_wave_segments):
    """Bit for bit against a render that reads every wave, rays from outside and inside
    (a network whose answers do not depend on its batch); a small wave budget splits the
    waves differently and changes nothing either."""
    ball = mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    origins, directions = view(30, ball)
    rng = np.random.default_rng(5)
    origins = np.concatenate([origins, rng.uniform(bend.min(0), bend.max(0), (200, 3))])
    directions = np.concatenate([directions, rng.normal(size=(200, 3))])
    network = DeviceRandomNetwork(albedo=albedo)
    table = np.array([[0.2, 0.4, 0.6], [0.9, 0.1, 0.0]], np.float32)
    every, every_stats = render.neural_passes(network, grid, table, cells, origins,
                                              directions, lanes=lanes,
                                              max_wave_segments=max_wave_segments)
    assert every.hit.sum() > 200 and (~every.hit).sum() > 200
    for per_read in (3, 16):
        got, stats = render.neural_passes(network, grid, table, cells, origins, directions,
                                          lanes=lanes, max_wave_segments=max_wave_segments,
                                          waves_per_read=per_read)
        for name in PASSES:
            np.testing.assert_array_equal(getattr(got, name), getattr(every, name))
        assert stats["truncated"] == every_stats["truncated"] == 0
        assert stats["waves"] >= every_stats["waves"]


def test_the_fields_at_every_segment_give_the_passes_of_the_fields_at_the_candidates():
    """The network's normal and albedo fields, evaluated at every segment and kept at the
    candidates, against the fields at the candidates alone: the same hits, materials,
    distances and normals; the albedo within float32 rounding (the fields' batches hold
    other rows)."""
    ball = mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    origins, directions = view(24, ball)
    network = small_network(0.6, 0.4)
    every, _ = render.neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                    directions, lanes=1)
    got, _ = render.neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                  directions, lanes=1, waves_per_read=4)
    assert every.hit.sum() > 50
    for name in ("hit", "material", "distance"):
        np.testing.assert_array_equal(getattr(got, name), getattr(every, name))
    np.testing.assert_allclose(got.normal, every.normal, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got.albedo, every.albedo, rtol=0, atol=1e-6)


def test_a_render_that_never_reads_is_refused():
    mesh, grid, bend = bent_ball(6)
    with pytest.raises(VDNIFError, match="every 1 or more waves, not 0"):
        render.neural_passes(DeviceRandomNetwork(), grid, mesh.albedo_table(),
                             DeviceCells(grid, corners=bend), np.zeros((1, 3)),
                             np.ones((1, 3)), waves_per_read=0)
