"""tools/gpu_check.py: without a CUDA device that torch and Warp both see it says so in one
line and exits at once; with one (skipped here otherwise) it trains and renders on the GPU,
the real network's Warp encoder inside the wave loop, and its renders match the CPU's."""

import pathlib
import time

import pytest
import torch
from tool_errors import load_tool, one_error_line

from vdnif_addon.kernels import runtime

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "gpu_check.py"
CUDA = torch.cuda.is_available() and runtime.cuda_device_count() > 0


@pytest.mark.skipif(CUDA, reason="this machine has a CUDA device")
def test_without_cuda_it_refuses_in_one_line_at_once():
    start = time.perf_counter()
    line = one_error_line(TOOL, [])
    assert "no CUDA device to check: torch" in line and "sees no CUDA device" in line
    assert time.perf_counter() - start < 60


def test_a_gpu_that_warp_cannot_use_is_refused(monkeypatch):
    """torch sees a GPU, Warp's CUDA 13 wheels do not (an old driver): refused, naming it."""
    tool = load_tool(TOOL)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(runtime, "cuda_device_count", lambda: 0)
    assert "Warp" in tool.cuda_problem() and "CUDA 13" in tool.cuda_problem()
    assert tool.main([]) == 1
    monkeypatch.setattr(runtime, "cuda_device_count", lambda: 1)
    assert tool.cuda_problem() is None


@pytest.mark.slow
@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_the_gpu_check_passes_on_cuda():
    """The real trained network on the GPU and on the CPU, in capped waves and under a side
    stream: hits equal but at most one pixel, distances within 1e-5."""
    said = []
    assert load_tool(TOOL).check(steps=1000, size=64, say=said.append), "\n".join(said)


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_batches_move_from_host_memory_to_the_gpu_unchanged():
    """The pinned, asynchronous copy of each batch gives the rows a CPU run draws."""
    from test_cuda_memory import shards

    from vdnif_addon.settings import Heads, TrainConfig
    from vdnif_addon.training.data import Batches, split_data
    from vdnif_addon.training.distributed import ProcessGroup

    config = TrainConfig(val_fraction=0.25, batch_size=64, device="cpu")
    heads = Heads(albedo=True, material_count=2)
    got = {}
    for device in ("cpu", "cuda:0"):
        rows, _, _, _ = split_data(shards(), config, heads, torch.device(device), ProcessGroup())
        batches = Batches(rows, 64, seed=3)
        got[device] = [batches.next() for _ in range(3)]
    for cpu, gpu in zip(got["cpu"], got["cuda:0"]):
        for key, value in cpu.items():
            assert gpu[key].device.type == "cuda" and torch.equal(gpu[key].cpu(), value), key


def test_the_benchmark_runs_on_the_cpu_and_counts_what_a_frame_costs():
    """The GPU benchmark's code on the CPU at a small size with an untrained network of the
    ball: every figure present, the frame's host reads and Warp launches counted, the
    segment MLP's multiply-adds and table reads those of the default network (84 encoded
    values, 84-64-64-64 and its heads; 2 (1 + 2 * 3) points, 2 levels, 8 corners)."""
    tool = load_tool(TOOL)
    from vdnif_addon.model.network import IntersectionNetwork
    from vdnif_addon.settings import Heads, NetworkConfig

    mesh, grid, bend = tool.ball(resolution=6, rings=8, sides=12)
    heads = mesh.heads()
    network = IntersectionNetwork(NetworkConfig(heads=Heads(
        albedo=heads["albedo"], material_count=heads["material_count"])))
    said = []
    figures = tool.benchmark(network, mesh, grid, bend, device="cpu", frame=(24, 16),
                             sweep=(256, 1024), repeats=1, say=said.append)
    frame = figures["frame"]
    assert frame["rays"] == 24 * 16 and frame["render_s"] > 0 and frame["warp_cast_s"] > 0
    assert frame["host_reads"] >= frame["waves"] >= 1 and frame["warp_launches"] > frame["waves"]
    outputs = network.mlp[-1].out_features          # the heads the segment MLP answers
    assert network.encoder.output_dim == 84
    assert figures["network_cost"]["macs"] == 84 * 64 + 2 * 64 * 64 + 64 * outputs
    assert figures["network_cost"]["table_reads"] == 224
    precisions = ["float32"] + (["bfloat16"] if runtime.bfloat16_native(torch.device("cpu"))
                                else [])
    assert [(r["precision"], r["segments"]) for r in figures["network"]] == [
        (p, n) for p in precisions for n in (256, 1024)]
    assert all(r["segments_per_s"] > 0 and r["share_of_flops"] is None
               for r in figures["network"])
    assert figures["peaks"] is None and "no ray-tracing cores" in figures["note"]
    assert len(said) == 1 + len(figures["network"])
