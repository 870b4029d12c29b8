"""How the encoder's launches are placed: split over CPU threads (a Warp CPU launch runs on
one), or on the Warp stream of torch's current CUDA stream.

Warp CPU launches from several threads at once. Warp's documentation promises nothing here (it
says a CPU launch is synchronous and runs serially); what makes it safe for this package's
kernels, read in Warp 1.19: a launch builds its arguments per call and calls the compiled
entry through ctypes, which releases the GIL; the entry loops over the tasks passing each
index as an argument (an older Warp kept it in a global); the one global a launch writes is
the tile storage pointer, which only tile kernels read, and no kernel here uses tiles. So
launches that write disjoint memory may run at once: the encoder's slices here, and the
renderer's lanes (``inference.neural_render``). Kernel modules are loaded before
(``runtime.load``, one at a time). The tests hold threaded launches to one launch's result,
run after run (``tests/kernels/test_encoder_threads.py``, ``tests/inference/test_render.py``)."""

from __future__ import annotations

from typing import Any

import torch
import warp as wp

from .. import threads

MIN_SLICE_POINTS = 2048
"""Points per CPU slice at least: below this a thread's start costs more than it saves."""

_STREAMS: dict[tuple[int | None, int], wp.Stream] = {}
"""(GPU index, CUDA stream handle) -> the Warp stream that wraps it (``warp_stream``)."""


def warp_stream(stream: torch.cuda.Stream) -> wp.Stream:
    """The Warp stream of a torch CUDA stream, made on first use and reused: a Warp stream
    made per launch registers the torch stream with Warp every time and unregisters it when
    collected, while the stream is still current under ``torch.cuda.stream``."""
    key = (stream.device.index, stream.cuda_stream)
    found = _STREAMS.get(key)
    if found is None:
        found = _STREAMS.setdefault(key, wp.stream_from_torch(stream))
    return found


def parts(device: str, count: int, workers: int | None = None) -> int:
    """Slices a launch over ``count`` points is split into: one per CPU thread of ``workers``
    (default ``threads.encoder_threads()``) with at least ``MIN_SLICE_POINTS`` points each,
    one on CUDA (a CUDA launch is parallel already)."""
    if not str(device).startswith("cpu"):
        return 1
    return max(1, min(workers or threads.encoder_threads(), count // MIN_SLICE_POINTS))


def bounds(count: int, parts: int, most: int | None = None) -> list[tuple[int, int]]:
    """``(first, stop)`` of at least ``parts`` slices of ``count`` points, as even as may be,
    each of at most ``most`` points (at least one)."""
    step = -(-count // parts) if most is None else min(most, -(-count // parts))
    step = max(1, step)
    return [(first, min(first + step, count)) for first in range(0, count, step)]


def run(kernel: Any, device: str, stream: wp.Stream | None, workers: int,
        jobs: list[tuple[int, list[Any]]]) -> None:
    """Launches ``kernel`` once per (dim, arguments) of ``jobs``. With ``workers`` > 1
    (the CPU only) job i runs on worker i % workers of ``threads.launch_pool(workers)``,
    each worker's jobs in order, the workers at once (safe: see the module), each worker's
    arithmetic flushing denormals as the caller's does (``threads.flush_denormals``)."""
    flushed = threads.denormals_flushed()

    def in_order(share: list[tuple[int, list[Any]]]) -> None:
        threads.flush_denormals(flushed)
        for dim, inputs in share:
            wp.launch(kernel, dim=dim, inputs=inputs, device=device, stream=stream)

    if workers == 1:
        in_order(jobs)
    else:
        shares = [jobs[k::workers] for k in range(workers)]
        list(threads.launch_pool(workers).map(in_order, shares))
