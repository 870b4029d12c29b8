"""Throughput of the network alone (no traversal): inference segments/s and training samples/s.

Run it as ``batch.py -- bench-network [--device cpu] [--repeats 5] [--json PATH]``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import torch

from .losses import make_weighting
from .network import Heads, IntersectionNetwork, NetworkConfig
from .train import Objective, resolve_device

PAPER_CONFIG = NetworkConfig(heads=Heads(albedo=True, material_count=4))
"""L=2, N_min=64, Fd=3, F=3, width 64, depth 3; albedo and a 4-material head."""


def _median_seconds(run: Callable[[], Any], device: torch.device, repeats: int) -> float:
    run()  # warm-up
    times = []
    for _ in range(repeats):
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
) -> dict[str, Any]:
    """Median timings of encoder + MLP inference on ``segments`` random segments and of a full
    training step (forward, losses, backward, Adam) on ``train_batch``; ``encode_fraction`` and
    ``mlp_fraction`` split the inference time between the encoding and the MLP."""
    dev = resolve_device(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        network = IntersectionNetwork(config).to(dev)
        p0, p1 = torch.rand(2, segments, 3).to(dev)
        n = train_batch
        batch = {
            "p0": torch.rand(n, 3),
            "p1": torch.rand(n, 3),
            "rest_len": torch.rand(n) * 0.03,
            "hit": torch.rand(n) < 0.5,
            "hit_frac": torch.rand(n),
            "normal": torch.nn.functional.normalize(torch.randn(n, 3), dim=1),
            "albedo": torch.rand(n, 3),
            "material": torch.randint(config.heads.material_count, (n,)),
        }
    batch = {key: value.to(dev) for key, value in batch.items()}

    with torch.inference_mode():
        infer = _median_seconds(lambda: network(p0, p1), dev, repeats)
        features = network.encoder(p0, p1)
        encode = _median_seconds(lambda: network.encoder(p0, p1), dev, repeats)
        mlp = _median_seconds(lambda: network.mlp(features), dev, repeats)

    objective = Objective(
        network, make_weighting("uncertainty", list(network.head_sizes)), voxel_size=0.03
    ).to(dev)
    optimizer = torch.optim.Adam(objective.parameters(), lr=1e-3)

    def train_step() -> None:
        optimizer.zero_grad(set_to_none=True)
        objective(batch)[0].backward()
        optimizer.step()

    step = _median_seconds(train_step, dev, repeats)
    return {
        "device": str(dev),
        "threads": torch.get_num_threads(),
        "config": config.to_dict(),
        "segments": segments,
        "train_batch": train_batch,
        "repeats": repeats,
        "infer_segments_per_s": segments / infer,
        "train_samples_per_s": train_batch / step,
        "encode_fraction": encode / (encode + mlp),
        "mlp_fraction": mlp / (encode + mlp),
    }
