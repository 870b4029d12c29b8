"""The encoder's CPU launches split over several threads (``kernels.launches``): the same
features and the same table gradient as one serial launch, bit for bit (the backward's
workers each scatter levels of their own), run after run, at sizes that split unevenly;
both also against the torch oracle (``oracles.encoding_torch``)."""

import contextlib

import pytest
import torch
from oracles import encoding_torch as oracle

from vdnif_addon import threads
from vdnif_addon.kernels import launches
from vdnif_addon.model.encoding import HashGrid, SegmentEncoder


@pytest.fixture
def encoder_threads():
    yield threads.use_encoder_threads
    threads.use_encoder_threads(None)


def features_and_gradient(encoder, p0, p1, weights):
    encoder.zero_grad(set_to_none=True)
    features = encoder(p0, p1)
    (features * weights).sum().backward()
    return features.detach(), encoder.grid.table.grad.clone()


@pytest.mark.parametrize("count", [2 * launches.MIN_SLICE_POINTS, 9_001, 20_011])
@pytest.mark.parametrize("workers", [2, 3, 4])
@pytest.mark.parametrize("levels", [1, 2, 3])
def test_threaded_launches_equal_one_launch_run_after_run(encoder_threads, count, workers,
                                                          levels):
    torch.manual_seed(count)
    # a small hashed table: many segments scatter into the same rows, so a lost update
    # between workers would show; levels that split evenly, unevenly or not at all
    encoder = SegmentEncoder(HashGrid(levels, 16, 2.0, 9, 3), pe_bands=2)
    with torch.no_grad():
        encoder.grid.table.uniform_(-1.0, 1.0)
    p0, p1 = torch.rand(2, count, 3)
    weights = torch.randn(count, encoder.output_dim)
    encoder_threads(1)
    assert launches.parts("cpu", count) == 1
    serial, serial_grad = features_and_gradient(encoder, p0, p1, weights)
    encoder_threads(workers)
    assert launches.parts("cpu", count) == min(workers, count // launches.MIN_SLICE_POINTS) > 1
    for _ in range(10):
        features, grad = features_and_gradient(encoder, p0, p1, weights)
        assert torch.equal(features, serial)
        assert torch.equal(grad, serial_grad)


def test_threaded_gradient_equals_the_torch_oracle(encoder_threads):
    """The tolerance of the one-launch kernel's own oracle test
    (tests/kernels/test_encoding_kernel.py)."""
    torch.manual_seed(3)
    encoder = SegmentEncoder(HashGrid(2, 12, 2.0, 10, 2), pe_bands=1)
    with torch.no_grad():
        encoder.grid.table.uniform_(-1.0, 1.0)
    reference = oracle.from_product(encoder, correctly_rounded=True)
    p0, p1 = torch.rand(2, 3 * launches.MIN_SLICE_POINTS, 3)
    weights = torch.randn(p0.shape[0], encoder.output_dim)
    encoder_threads(3)
    features, grad = features_and_gradient(encoder, p0, p1, weights)
    reference.zero_grad(set_to_none=True)
    expected = reference(p0, p1)
    (expected * weights).sum().backward()
    expected_grad = reference.grid.table.grad.t()
    torch.testing.assert_close(features, expected.detach(), rtol=1e-6, atol=1e-6)
    scale = expected_grad.abs().max().item()
    torch.testing.assert_close(grad, expected_grad, rtol=1e-6, atol=1e-6 * scale)


def test_small_batches_and_cuda_stay_one_launch(encoder_threads):
    encoder_threads(8)
    assert launches.parts("cpu", launches.MIN_SLICE_POINTS * 2 - 1) == 1
    assert launches.parts("cpu", launches.MIN_SLICE_POINTS * 100) == 8
    assert launches.parts("cuda:0", launches.MIN_SLICE_POINTS * 100) == 1


def values_at_network_calls(probe, **options):
    """``probe()`` at each network call of a small render of the bent ball."""
    import numpy as np
    from test_render import RandomNetwork, bent_ball

    from vdnif_addon.inference import neural_render as render
    from vdnif_addon.kernels.cells import DeviceCells
    from vdnif_addon.tracing import rays

    seen = []

    class Recording(RandomNetwork):
        def predict(self, *args, **kwargs):
            seen.append(probe())
            return super().predict(*args, **kwargs)

    mesh, grid, bend = bent_ball()
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.0, 0.0, 1.0]),
                                          24, 16)
    render.neural_passes(Recording(), grid, np.ones((2, 3), np.float32), cells, origins,
                         directions, **options)
    return seen


def test_each_lane_encodes_on_its_share_of_the_cores(encoder_threads):
    """Each lane runs its own network calls on a lane thread of its own with its share of
    the cores (at least one); one lane splits its encoder as set, several run each one's
    on its own thread; the setting comes back after."""
    import threading

    def probe():
        return threading.current_thread().name, threads.encoder_threads(), threads.cores()

    encoder_threads(4)
    threads.use_cores(4)
    try:
        for lanes, share, split in ((1, 4, 4), (2, 2, 1), (3, 1, 1)):
            seen = values_at_network_calls(probe, lanes=lanes)
            assert seen and {(cores, encoder) for _, encoder, cores in seen} == {(share, split)}
            names = {name for name, _, _ in seen}
            assert names == {threading.current_thread().name,
                             *(f"vdnif-lane-{lane}" for lane in range(1, lanes))}
            assert threads.encoder_threads() == 4 and threads.cores() == 4
    finally:
        threads.use_cores(None)


def test_the_render_caps_torch_threads_and_gives_them_back(monkeypatch):
    """The render's network runs on at most ``RENDER_TORCH_THREADS`` of torch's threads;
    torch's own count comes back after it, and a count under the cap is left alone."""
    monkeypatch.setattr(threads, "RENDER_TORCH_THREADS", 1)
    before = torch.get_num_threads()
    try:
        for own, during in ((2, 1), (1, 1)):
            torch.set_num_threads(own)
            seen = values_at_network_calls(torch.get_num_threads)
            assert seen and set(seen) == {during}
            assert torch.get_num_threads() == own
    finally:
        torch.set_num_threads(before)


def test_a_one_core_setting_walks_and_encodes_on_the_calling_thread(monkeypatch):
    """``threads.use_cores`` (a benchmark's thread setting): with one core the render walks
    one lane and ``predict`` does not encode beside its MLP; with two (torch on one) it walks
    two lanes of a large image (one of a small one, one on CUDA) and encodes beside."""
    import threading

    from vdnif_addon.model.network import IntersectionNetwork
    from vdnif_addon.settings import NetworkConfig
    from vdnif_addon.threads import MIN_LANE_RAYS, walk_lanes

    network = IntersectionNetwork(NetworkConfig(levels=2, base_resolution=8, log2_table_size=10,
                                                width=16, depth=1, pe_bands=1))
    network.eval()
    encode, seen = network.encoder.forward, []

    def recording(*args, **kwargs):
        seen.append(threading.current_thread() is threading.main_thread())
        return encode(*args, **kwargs)

    monkeypatch.setattr(network.encoder, "forward", recording)
    p0, p1 = torch.rand(2, 300, 3)
    torch_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for cores, beside in ((1, False), (2, True)):
            threads.use_cores(cores)
            seen.clear()
            network.predict(p0, p1, (p1 - p0).norm(dim=1), 0.1, batch=100)
            assert walk_lanes("cpu", 64 * MIN_LANE_RAYS) == cores
            assert walk_lanes("cpu", 2 * MIN_LANE_RAYS - 1) == 1
            assert walk_lanes("cuda", 64 * MIN_LANE_RAYS) == 1
            assert len(seen) == 3 and all(on_main is not beside for on_main in seen)
    finally:
        threads.use_cores(None)
        torch.set_num_threads(torch_threads)


@pytest.mark.parametrize("count, parts, most", [(10, 3, None), (10, 3, 2), (7, 8, None),
                                                (0, 2, None), (5, 1, 0)])
def test_launch_bounds_cover_the_points_once_in_order(count, parts, most):
    bounds = launches.bounds(count, parts, most)
    assert [i for first, stop in bounds for i in range(first, stop)] == list(range(count))
    sizes = [stop - first for first, stop in bounds]
    assert len(bounds) >= min(parts, count)
    # one step for every slice but the last, which holds the rest
    assert len(set(sizes[:-1])) <= 1 and all(0 < size <= sizes[0] for size in sizes)
    if most:
        assert sizes[0] <= most


def test_at_once_runs_every_task_beside_the_others_and_raises_the_first_error():
    """Four tasks that each wait for all four to have started: run one after the other
    they would time out. Results come back in order; a task's error reaches the caller
    after every thread has ended."""
    import threading

    barrier = threading.Barrier(4, timeout=10)

    def task(index):
        barrier.wait()
        return index * index, threading.current_thread().name

    results = threads.at_once(task, 4, "test-lane")
    assert [value for value, _ in results] == [0, 1, 4, 9]
    assert len({name for _, name in results}) == 4
    ended = []

    def failing(index):
        if index == 1:
            raise ValueError("lane 1 broke")
        ended.append(index)

    with pytest.raises(ValueError, match="lane 1 broke"):
        threads.at_once(failing, 3, "test-lane")
    assert sorted(ended) == [0, 2]


def test_the_workers_flush_denormals_as_their_caller_does(encoder_threads):
    """A table of denormal values, read on a thread that flushes denormals (a training's
    steps: ``train.flushed_denormals``), gives zero features on one thread and the same bits
    split over workers; on a thread that does not flush them, the same bits on both, not
    zero. A worker that flushed for a training keeps no flush for a later caller."""
    from vdnif_addon.training.train import flushed_denormals

    if not torch.set_flush_denormal(False):
        pytest.skip("this CPU cannot flush denormals")
    torch.manual_seed(5)
    encoder = SegmentEncoder(HashGrid(2, 16, 2.0, 9, 3), pe_bands=1)
    with torch.no_grad():
        encoder.grid.table.fill_(1e-39)                 # below float32's smallest normal
    count = 4 * launches.MIN_SLICE_POINTS
    p0, p1 = torch.rand(2, count, 3)
    weights = torch.randn(count, encoder.output_dim)
    results = {}
    for flushed in (True, False, True, False):
        with flushed_denormals() if flushed else contextlib.nullcontext():
            for workers in (1, 2):
                encoder_threads(workers)
                results.setdefault((flushed, workers), []).append(
                    features_and_gradient(encoder, p0, p1, weights)[0])
    for flushed in (True, False):
        for one, split in zip(results[flushed, 1], results[flushed, 2]):
            assert torch.equal(one, split)
        assert (torch.count_nonzero(results[flushed, 1][0]) == 0) == flushed
