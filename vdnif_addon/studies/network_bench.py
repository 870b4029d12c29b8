"""Throughput of the network alone (no traversal): inference segments/s and training samples/s.

Run it as ``batch.py -- bench-network [--device cpu] [--precision P] [--threads N]
[--repeats 5] [--json PATH]``.
Every figure is a median over ``repeats`` timed runs after one warm-up run; the kernels are
compiled or loaded before either, and that time is reported apart (``kernels_s``).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import torch

from ..kernels import runtime
from ..model.network import IntersectionNetwork, readout, resolve_precision
from ..settings import DEFAULT_PRECISION, Heads, NetworkConfig, TrainConfig
from ..training.distributed import resolve_device
from ..training.losses import make_weighting
from ..training.train import Objective, TrainingStep

PAPER_CONFIG = NetworkConfig(heads=Heads(albedo=True, material_count=4))
"""L=2, N_min=64, Fd=3, F=3, width 64, depth 3; albedo and a 4-material head."""

VOXEL_SIZE = 0.03
"""Rest-space voxel size of the benchmark's segments (only scales the distance readout)."""


def _median_seconds(run: Callable[[], Any], device: torch.device, repeats: int) -> float:
    run()  # warm-up
    times = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        started = time.perf_counter()
        run()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def benchmark_network(
    device: str = "auto",
    segments: int = 2**16,
    train_batch: int = 2**14,
    repeats: int = 5,
    config: NetworkConfig = PAPER_CONFIG,
    precision: str = DEFAULT_PRECISION,
) -> dict[str, Any]:
    """Median timings of inference and of a training step on random segments, the MLPs of
    both in ``precision`` as a render and training resolve it on the device
    (``resolve_precision``; the result's ``precision``).

    ``infer_segments_per_s``: ``IntersectionNetwork.predict`` on ``segments`` segments (the
    renderer's call: encoder, MLP, heads, readout; on the CPU the encoder of one batch runs
    beside the MLP of the previous one). ``encode_fraction`` / ``mlp_fraction`` split the
    time of the two parts run one after the other (the encoder alone; the MLP, heads and
    readout alone, on the same features), and ``serial_segments_per_s`` is the throughput
    of that sequence: the gain of the overlap is its ratio to ``infer_segments_per_s``.
    ``train_samples_per_s``: one training step as ``train.py`` takes it (forward, losses,
    backward, finite check, Adam with its learning-rate decay) on ``train_batch`` samples.
    """
    dev = resolve_device(device)
    kernels_s = runtime.load_all(runtime.device(dev))       # said apart from the speeds
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        network = IntersectionNetwork(config).to(dev)
        p0, p1 = torch.rand(2, segments, 3)
        rest_len = torch.rand(segments) * VOXEL_SIZE
        n = train_batch
        batch = {
            "p0": torch.rand(n, 3),
            "p1": torch.rand(n, 3),
            "rest_len": torch.rand(n) * VOXEL_SIZE,
            "hit": torch.rand(n) < 0.5,
            "hit_frac": torch.rand(n),
            "normal": torch.nn.functional.normalize(torch.randn(n, 3), dim=1),
            "albedo": torch.rand(n, 3),
            "material": torch.randint(config.heads.material_count, (n,)),
        }
    p0, p1, rest_len = p0.to(dev), p1.to(dev), rest_len.to(dev)
    batch = {key: value.to(dev) for key, value in batch.items()}

    arithmetic = resolve_precision(precision, dev)
    network.eval()
    network.precision = arithmetic
    infer = _median_seconds(lambda: network.predict(p0, p1, rest_len, VOXEL_SIZE), dev, repeats)
    with torch.inference_mode():
        features = network.encoder(p0, p1)
        encode = _median_seconds(lambda: network.encoder(p0, p1), dev, repeats)
        with network.mlp_arithmetic(dev):
            mlp = _median_seconds(
                lambda: readout(network.heads(features), config.distance_mode, VOXEL_SIZE,
                                rest_len),
                dev,
                repeats,
            )
    network.train()
    network.precision = "float32"

    objective = Objective(
        network, make_weighting("uncertainty", list(network.head_sizes)), VOXEL_SIZE,
        precision=arithmetic).to(dev)
    step = TrainingStep(objective, TrainConfig(steps=repeats + 1, device=dev.type))
    train = _median_seconds(lambda: step(batch), dev, repeats)
    return {
        "device": str(dev),
        "threads": torch.get_num_threads(),
        "precision": arithmetic,
        "config": config.to_dict(),
        "segments": segments,
        "train_batch": train_batch,
        "repeats": repeats,
        "kernels_s": kernels_s,
        "infer_segments_per_s": segments / infer,
        "serial_segments_per_s": segments / (encode + mlp),
        "encode_segments_per_s": segments / encode,
        "mlp_segments_per_s": segments / mlp,
        "train_samples_per_s": train_batch / train,
        "encode_fraction": encode / (encode + mlp),
        "mlp_fraction": mlp / (encode + mlp),
    }
