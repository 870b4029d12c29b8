"""How many threads torch's CPU work uses: one default, read by the batch commands, the UI's
training worker and ``bench-network``.

The encoder is a Warp kernel that runs on one thread of its own (a Warp CPU launch is serial),
beside the MLP in ``predict``; torch's threads run the MLP. So the default leaves one core to
the encoder: torch gets every core but one. With every core, torch's OpenMP workers spin
beside the encoder's thread, and whenever another process takes a core their barrier waits on
a descheduled thread, slowing inference and training many times (DESIGN section 8).
"""

from __future__ import annotations

import collections
import contextlib
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")

ENCODER_CORES = 1
"""Cores left to the encoder's thread (a Warp CPU launch runs on one)."""

RENDER_TORCH_THREADS = 4
"""Torch threads at most while a render's network runs: a wave's batch (thousands to tens of
thousands of segments) is too small to gain from more, and on many cores more made a large
render slower (docs/performance.md, many cores)."""


def machine_cores() -> int:
    """The cores this process may run on."""
    allowed = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    return len(allowed) if allowed else os.cpu_count() or 1


_cores = {"count": None}


MIN_LANE_RAYS = 8192
"""Rays per lane at least: a lane's wave costs a fixed overhead on its thread (launches, a
network call) that short lanes do not repay. On 2 cores, bunny model: two lanes rendered
128x128 1.4-1.6x faster than one, and 64x64 (2,048 rays a lane) no faster
(docs/performance.md, threads)."""

_lane = threading.local()


def walk_lanes(device: object, rays: int) -> int:
    """Lanes a render or a walk of ``rays`` rays runs at once: one per core this process may
    use (``cores()``) on the CPU, each of at least ``MIN_LANE_RAYS`` rays; one on CUDA,
    where a launch is parallel already. ``device``: a torch or Warp device, or its name."""
    if not str(device).startswith("cpu"):
        return 1
    return max(1, min(cores(), rays // MIN_LANE_RAYS))


def cores() -> int:
    """The cores this thread's work may use: a render lane's share (``lane_cores``), else
    ``use_cores``'s count, else ``machine_cores()``."""
    return getattr(_lane, "cores", None) or _cores["count"] or machine_cores()


@contextlib.contextmanager
def lane_cores(count: int, encoder: int | None = None) -> Iterator[None]:
    """Within the block, on this thread, ``cores()`` is ``count``, a render lane's share of
    the cores that its network keeps to while the other lanes run beside it, and
    ``encoder_threads()`` is ``encoder`` where given (one where several lanes run: the
    launch pool is shared, and their split launches would queue behind each other)."""
    before = getattr(_lane, "cores", None), getattr(_lane, "encoder", None)
    _lane.cores, _lane.encoder = count, encoder
    try:
        yield
    finally:
        _lane.cores, _lane.encoder = before


def use_cores(count: int | None) -> None:
    """Makes ``cores()`` ``count`` (None: the machine's): a benchmark's thread setting, so
    that the renderer walks one lane per core of the setting and ``predict`` encodes beside
    the MLP only where the setting has a core for it."""
    _cores["count"] = count


def default_threads() -> int:
    """Torch threads by default: the cores this process may use, less ``ENCODER_CORES``, at
    least one."""
    return max(1, cores() - ENCODER_CORES)


def use_threads(threads: int | None = None) -> int:
    """Sets torch's intra-op threads to ``threads`` (default ``default_threads()``); returns
    the count in use. Imports torch."""
    import torch

    torch.set_num_threads(threads or default_threads())
    return torch.get_num_threads()


@contextlib.contextmanager
def torch_threads_at_most(count: int) -> Iterator[None]:
    """Within the block torch uses at most ``count`` threads; its own count comes back
    after. Imports torch."""
    import torch

    before = torch.get_num_threads()
    if before <= count:
        yield
        return
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


_denormals = threading.local()


def denormals_flushed() -> bool:
    """Whether this thread's CPU float arithmetic flushes denormals (``flush_denormals``)."""
    return getattr(_denormals, "flushed", False)


def flush_denormals(flushed: bool) -> None:
    """This thread's CPU float arithmetic reads and writes numbers below float32's smallest
    normal as zero (``flushed``) or as they are (a thread's default), through
    ``torch.set_flush_denormal``. ``launch_pool``'s workers take their caller's setting for
    each split launch (``kernels.launches.run``): a launch then rounds alike on any number of
    cores, and a training's encoder runs on its workers as its steps run, flushed. Imports
    torch."""
    if denormals_flushed() != flushed:
        import torch

        torch.set_flush_denormal(flushed)
        _denormals.flushed = flushed


_pool: dict[int, ThreadPoolExecutor] = {}
_pool_lock = threading.Lock()
_encoder = {"threads": None}


def encoder_threads() -> int:
    """CPU threads the encoder's launches are split over: a render lane's (``lane_cores``),
    else ``use_encoder_threads``'s count, else every core this process may use (training
    runs the encoder and the MLP one after the other, so while it encodes torch's threads
    wait)."""
    return getattr(_lane, "encoder", None) or _encoder["threads"] or cores()


def use_encoder_threads(count: int | None) -> None:
    """Splits the encoder's CPU launches over ``count`` threads (None: every core)."""
    _encoder["threads"] = count


def launch_pool(count: int | None = None) -> ThreadPoolExecutor:
    """``count`` worker threads (default ``encoder_threads()``) that run the slices of a
    split Warp CPU launch (the encoder's, a baseline's casts), made once per process and
    count; the pool of one gathers the training's next batch (a one-slice launch runs on its
    caller's thread)."""
    with _pool_lock:
        count = count or encoder_threads()
        if count not in _pool:
            _pool[count] = ThreadPoolExecutor(count, thread_name_prefix="vdnif-launch")
        return _pool[count]


def in_order(items: Sequence[Any], work: Callable[[Any], T], count: int, name: str
             ) -> Iterator[T]:
    """``work(item)`` of each item, yielded in order, at most ``count`` running at once on
    threads of their own named ``name``: an error is raised where its item comes, and a
    result is held only until it is taken (at most ``count`` results are alive)."""
    with ThreadPoolExecutor(count, thread_name_prefix=name) as pool:
        pending: collections.deque[Future[T]] = collections.deque()
        for item in items:
            pending.append(pool.submit(work, item))
            if len(pending) == count:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


def at_once(work: Callable[[int], T], count: int, name: str) -> list[T]:
    """``[work(0), ..., work(count - 1)]``, each on a thread of its own, all at once: 0 on
    this thread, the others on threads started for them and named ``name-i``. Not a pool: a
    pool's worker may take a second task before another worker takes the first, and run the
    two one after the other. The first error raised is raised here, after every thread ends."""
    results: list[Any] = [None] * count
    errors: list[BaseException] = []

    def run(index: int) -> None:
        try:
            results[index] = work(index)
        except BaseException as error:      # handed to the caller's thread below
            errors.append(error)

    started = [threading.Thread(target=run, args=(index,), name=f"{name}-{index}")
               for index in range(1, count)]
    for thread in started:
        thread.start()
    run(0)
    for thread in started:
        thread.join()
    if errors:
        raise errors[0]
    return results
