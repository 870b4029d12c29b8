"""Running out of memory as the user's problem: torch's and Warp's allocation failures (on a
GPU or the host) become one VDNIFError line that says what to lower, and torch's cached GPU
memory is handed back once a job is over.

Imports neither torch nor Warp: a failure is recognised by its type where torch is loaded,
else by the wording both libraries use.
"""

from __future__ import annotations

import contextlib
import gc
import sys
from collections.abc import Iterator

from .errors import VDNIFError

CPU_TRAINING_ADVICE = "lower the batch size or the hash table size (log2 table size)"
TRAINING_ADVICE = f"{CPU_TRAINING_ADVICE}, or train on the CPU"
"""What a training that ran out of memory can lower (on a GPU; on the CPU, which has no
CPU to move to, ``CPU_TRAINING_ADVICE``)."""

CPU_RENDER_ADVICE = "lower the image size"
RENDER_ADVICE = f"{CPU_RENDER_ADVICE}, or render on the CPU"
"""What a render that ran out of memory can lower (the rays' state is per pixel; a wave's
buffers are capped by ``limits.MAX_WAVE_SEGMENTS``)."""

_WORDING = ("out of memory", "Failed to allocate", "can't allocate memory")
"""torch's CUDA ("CUDA out of memory"), Warp's ("Failed to allocate N bytes on device") and
torch's CPU allocator's ("can't allocate memory") messages."""


def is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is an allocation failure of torch, Warp or numpy."""
    if isinstance(exc, MemoryError):
        return True
    torch = sys.modules.get("torch")
    if torch is not None and isinstance(exc, torch.cuda.OutOfMemoryError):
        return True
    return isinstance(exc, RuntimeError) and any(words in str(exc) for words in _WORDING)


def _detail(exc: BaseException) -> str:
    """The first two sentences of the failure's first line (torch's goes on for lines)."""
    lines = str(exc).strip().splitlines()
    first = lines[0] if lines else type(exc).__name__
    return ". ".join(first.split(". ")[:2]).rstrip(". ")


def on_gpu(exc: BaseException) -> bool:
    """Whether the allocation failure ``exc`` was a GPU's (torch's CUDA error, or Warp's
    naming a CUDA device), not the host's."""
    torch = sys.modules.get("torch")
    if torch is not None and isinstance(exc, torch.cuda.OutOfMemoryError):
        return True
    return "cuda" in str(exc).lower()


@contextlib.contextmanager
def out_of_memory(task: str, advice: str, cpu_advice: str | None = None) -> Iterator[None]:
    """Turns an allocation failure inside into ``VDNIFError("<task> ran out of memory
    (<what failed>): <advice>")``, with ``cpu_advice`` instead when given and the host's
    memory ran out (moving to the CPU is then no way out); any other exception passes
    unchanged."""
    try:
        yield
    except VDNIFError:
        raise
    except Exception as exc:
        if not is_out_of_memory(exc):
            raise
        said = advice if cpu_advice is None or on_gpu(exc) else cpu_advice
        raise VDNIFError(f"{task} ran out of memory ({_detail(exc)}): {said}") from None


def release_cached_memory() -> None:
    """Hands the GPU memory that torch keeps cached for reuse back to the driver, so that
    Warp's allocations (a render) and other programs can have it; nothing where this process
    never used CUDA."""
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_initialized():
        gc.collect()                # a network left in a reference cycle holds its tensors
        torch.cuda.empty_cache()
