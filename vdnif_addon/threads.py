"""How many threads torch's CPU work uses: one default, read by the batch commands, the UI's
training worker and ``bench-network``.

The encoder is a Warp kernel that runs on one thread of its own (a Warp CPU launch is serial),
beside the MLP in ``predict``; torch's threads run the MLP. So the default leaves one core to
the encoder: torch gets every core but one. Measured on the project's 2-core machine with
``bench-network --threads 1`` / ``--threads 2`` (paper setting; medians of 5; other processes
were running, so figures moved by tens of percent from run to run):

- inference (``predict``): 0.45-0.69 M segments/s with 1 torch thread, 0.37-0.38 M with 2 (the
  2 threads' OpenMP workers spin beside the encoder's thread; one after the other the two
  parts reach 0.41-0.47 M either way);
- training: 0.18-0.21 M samples/s with 1 thread, 0.23 M with 2;
- whenever another process used a core, 2 threads fell to 0.04-0.1 M segments/s and
  0.01-0.02 M samples/s (OpenMP's barrier waits on a descheduled thread), 1 thread did not.
"""

from __future__ import annotations

import os

ENCODER_CORES = 1
"""Cores left to the encoder's thread (a Warp CPU launch runs on one)."""


def default_threads() -> int:
    """Torch threads by default: the cores this process may use, less ``ENCODER_CORES``, at
    least one."""
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    count = len(cores) if cores else os.cpu_count() or 1
    return max(1, count - ENCODER_CORES)


def use_threads(threads: int | None = None) -> int:
    """Sets torch's intra-op threads to ``threads`` (default ``default_threads()``); returns
    the count in use. Imports torch."""
    import torch

    torch.set_num_threads(threads or default_threads())
    return torch.get_num_threads()
