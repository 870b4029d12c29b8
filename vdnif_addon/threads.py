"""How many threads torch's CPU work uses: one default, read by the batch commands, the UI's
training worker and ``bench-network``.

The encoder is a Warp kernel that runs on one thread of its own (a Warp CPU launch is serial),
beside the MLP in ``predict``; torch's threads run the MLP. So the default leaves one core to
the encoder: torch gets every core but one. With every core, torch's OpenMP workers spin
beside the encoder's thread, and whenever another process takes a core their barrier waits on
a descheduled thread, slowing inference and training many times (DESIGN section 8).
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
