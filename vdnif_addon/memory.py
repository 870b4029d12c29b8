"""Running out of memory as the user's problem: torch's and Warp's allocation failures (on a
GPU or the host) become one VDNIFError line that says what to lower, and torch's cached GPU
memory is handed back once a job is over.

Imports neither torch nor Warp: a failure is recognised by its type where torch is loaded,
else by the wording both libraries use.
"""

from __future__ import annotations

import contextlib
import gc
import os
import pathlib
import shutil
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


def _cgroup_room() -> int | None:
    """Bytes this process's cgroup (v2) may still allocate, where it has a limit."""
    try:
        limit = pathlib.Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = pathlib.Path("/sys/fs/cgroup/memory.current").read_text().strip()
    except OSError:
        return None
    if limit == "max" or not limit.isdigit() or not used.isdigit():
        return None
    return max(int(limit) - int(used), 0)


MEMORY_LIMIT_VARIABLE = "VDNIF_MEMORY_LIMIT"
"""Environment variable: bytes (suffix K, M or G: binary units) a job may use at most, below
what the machine has free (a machine shared with other work)."""


def _memory_limit() -> int | None:
    """The bytes ``VDNIF_MEMORY_LIMIT`` grants, None where unset."""
    text = os.environ.get(MEMORY_LIMIT_VARIABLE, "").strip()
    if not text:
        return None
    scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(text[-1:].upper(), 1)
    try:
        value = float(text[:-1] if scale > 1 else text) * scale
    except ValueError:
        value = -1.0
    if not 0 <= value < 2**63:
        raise VDNIFError(f"environment variable {MEMORY_LIMIT_VARIABLE} {text!r} is not a "
                         "number of bytes (suffix K, M or G allowed)")
    return int(value)


def available_bytes() -> int | None:
    """Bytes of memory a job may still allocate here: the kernel's MemAvailable (free plus
    reclaimable caches) and free swap (slow, but a run that fits there finishes), or less
    where a cgroup limits this process or ``VDNIF_MEMORY_LIMIT`` says less; None where none
    can be read (then nothing is refused beforehand, and ``out_of_memory`` still words a
    failure)."""
    found = _memory_limit()
    system = None
    try:
        with open("/proc/meminfo") as info:
            fields = dict(line.split(":", 1) for line in info if ":" in line)
        if "MemAvailable" in fields:
            system = sum(int(fields[name].split()[0]) * 1024
                         for name in ("MemAvailable", "SwapFree") if name in fields)
    except (OSError, ValueError, IndexError):
        pass
    if system is None and hasattr(os, "sysconf"):
        try:
            system = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (OSError, ValueError, AttributeError):
            system = None
    for room in (system, _cgroup_room()):
        if room is not None:
            found = room if found is None else min(found, room)
    return found


DEVICE_ROWS_SHARE = 0.5
"""The training rows live on the GPU where they take at most this share of its free memory
when training starts: the rest holds the network, its optimizer state, the held-out rows and
each step's activations."""


def device_free_bytes(device: object) -> int | None:
    """Free bytes of a CUDA ``device`` (a torch device), None for any other device."""
    if getattr(device, "type", None) != "cuda":
        return None
    import torch

    return int(torch.cuda.mem_get_info(device)[0])


def gib(size: float) -> str:
    """``108 GiB``: a byte count in binary units, as the refusals word it."""
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{size:.0f} bytes"


def check_memory(what: str, need: float, advice: str, available: int | None = None) -> None:
    """Refuses, before the work, a job whose peak memory ``need`` (bytes, computed from its
    options) is more than this machine has free: ``VDNIFError("<what> needs about N of
    memory, more than the M free here: <advice>")``. ``available``: the free bytes
    (``available_bytes()`` unless given)."""
    if available is None:
        available = available_bytes()
    if available is not None and need > available:
        raise VDNIFError(f"{what} needs about {gib(need)} of memory, more than the "
                         f"{gib(available)} available here: {advice}")


def check_disk(what: str, need: float, folder: str | os.PathLike, advice: str) -> None:
    """Refuses, before the work, a job that would write ``need`` bytes into ``folder`` (or
    the nearest folder above it that exists) when its file system has less free."""
    place = pathlib.Path(folder).absolute()
    while not place.exists() and place != place.parent:
        place = place.parent
    try:
        free = shutil.disk_usage(place).free
    except OSError:
        return
    if need > free:
        raise VDNIFError(f"{what} needs about {gib(need)} on disk, more than the {gib(free)} "
                         f"free at '{place}': {advice}")
