"""Warp, initialized once: a per-machine kernel cache, quiet start-up, torch <-> Warp devices.

CPU kernels are compiled for the host CPU (``-march=native``), so a cache copied to another
machine can crash with an illegal instruction: the cache folder is keyed by the host's CPU
model and feature flags as well as Warp's version. The extension points the cache root at its
user folder (``set_cache_root``); batch runs use ``$VDNIF_KERNEL_CACHE`` or the user's cache
folder. The first compile of a kernel module takes seconds; ``load`` says so on stderr, and
the UI jobs' progress line while it runs (``worker.compile_line``).
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib
import os
import pathlib
import pkgutil
import platform
import sys
import threading
import time
from collections.abc import Iterator
from types import ModuleType
from typing import TYPE_CHECKING

import warp as wp

from ..errors import VDNIFError
from ..worker import KernelCompile

if TYPE_CHECKING:
    import torch

CACHE_ENV = "VDNIF_KERNEL_CACHE"

_lock = threading.Lock()
_loading = threading.Lock()
_state = {"ready": False, "root": None}
_loaded: set = set()

BVH_CONSTRUCTOR = "sah"
"""How every ``wp.Mesh`` builds its BVH, on the CPU and on CUDA alike. Warp's default is SAH on
the CPU and LBVH on CUDA: two trees traverse in another order, and where a ray meets two
triangles at the same distance (an edge, a vertex) each device could report another one. A
CUDA mesh built with SAH is built on the host and copied (slower to build than LBVH; meshes
are built once per object and refitted per pose)."""


def set_cache_root(path: str | os.PathLike) -> None:
    """Where kernel caches live (before the first kernel is used; later calls are ignored)."""
    with _lock:
        if not _state["ready"]:
            _state["root"] = pathlib.Path(path)


def _cpuinfo() -> list[str] | None:
    """The lines of ``/proc/cpuinfo``; None where it cannot be read (not Linux)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as info:
            return info.read().splitlines()
    except OSError:
        return None


def host_key() -> str:
    """12 hex digits naming this machine's CPU model and features and Warp's version."""
    cpu, lines = platform.processor() or platform.machine(), _cpuinfo()
    if lines is not None:
        wanted = ("model name", "flags", "Features", "CPU implementer", "CPU part")
        cpu = "\n".join(sorted({line.strip() for line in lines if line.startswith(wanted)}))
    text = f"{platform.system()}|{platform.machine()}|{cpu}|warp {wp.__version__}"
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def vector_extensions(flags: set[str]) -> str:
    """The widest vector extensions among a CPU's ``/proc/cpuinfo`` flags: with AVX-512 (and
    bfloat16) the MLP's matrix products and Embree's casts run several times faster than with
    AVX2, and AMX's tiles multiply bfloat16 matrices faster again, so two machines' timings
    compare only with these named."""
    if "avx512f" in flags:
        bf16 = [name for flag, name in (("avx512_bf16", "BF16"), ("amx_bf16", "AMX"))
                if flag in flags]
        return "AVX-512 with " + " and ".join(bf16) if bf16 else "AVX-512"
    return "AVX2" if "avx2" in flags else "no AVX2"


def bfloat16_native(device: torch.device) -> bool:
    """Whether ``device`` multiplies bfloat16 matrices in hardware: a CUDA GPU where torch
    says so, a CPU whose flags name AVX-512 BF16 or AMX (elsewhere torch emulates it, slower
    than float32)."""
    if device.type == "cuda":
        import torch

        return torch.cuda.is_bf16_supported()
    return bool(_cpu_fields().get("flags", set()) & {"avx512_bf16", "amx_bf16"})


def cpu_description() -> tuple[str, str | None]:
    """(this machine's CPU model, its ``vector_extensions``; None where the flags are not
    readable)."""
    fields = _cpu_fields()
    cpu = fields.get("model name") or platform.processor() or platform.machine()
    flags = fields.get("flags")
    return cpu, None if flags is None else vector_extensions(flags)


def _cpu_fields() -> dict:
    """The first CPU's ``model name`` (a string) and ``flags`` (a set) in ``/proc/cpuinfo``,
    those it names."""
    fields: dict = {}
    for line in _cpuinfo() or []:
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "model name" and key not in fields:
            fields[key] = value.strip()
        elif key == "flags" and key not in fields:
            fields[key] = set(value.split())
    return fields


def cache_dir() -> pathlib.Path:
    """The kernel cache folder of this machine."""
    root = _state["root"] or os.environ.get(CACHE_ENV)
    if root is None:
        base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
        root = pathlib.Path(base) / "vdnif" / "kernels"
    return pathlib.Path(root) / f"warp-{wp.__version__}-{host_key()}"


def _ready_cache(folder: pathlib.Path) -> None:
    """Creates the kernel cache ``folder``; a place where it cannot be (under a file, in a
    read-only folder) is a one-line VDNIFError naming it and where it came from, before
    Warp fails on its first compile."""
    source = ("the extension's user folder" if _state["root"] is not None
              else f"${CACHE_ENV}" if os.environ.get(CACHE_ENV) else "the user's cache folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        reason = exc.strerror.lower() if exc.strerror else str(exc)
        raise VDNIFError(f"kernel cache folder '{folder}' (from {source}) cannot be created: "
                         f"{reason}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise VDNIFError(f"kernel cache folder '{folder}' (from {source}) is not writable")


def cuda_driver_present() -> bool:
    """Whether the NVIDIA driver library that Warp loads for CUDA can be loaded here."""
    names = {"win32": ("nvcuda.dll",), "linux": ("libcuda.so", "libcuda.so.1")}.get(
        sys.platform, ())
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


@contextlib.contextmanager
def _quiet_stderr(quiet: bool) -> Iterator[None]:
    """Standard error (the file descriptor: Warp's native library writes to it) silenced
    while ``quiet``: without a driver Warp warns on every start that CUDA is unavailable,
    which is the expected case on a machine without an NVIDIA GPU, not news."""
    if not quiet:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def init() -> ModuleType:
    """Warp, initialized once with this machine's kernel cache; returns the module."""
    with _lock:
        if not _state["ready"]:
            wp.config.log_level = wp.LOG_WARNING
            folder = cache_dir()
            _ready_cache(folder)
            wp.config.kernel_cache_dir = str(folder)
            with _quiet_stderr(not cuda_driver_present()):
                wp.init()
            _state["ready"] = True
    return wp


def cuda_device_count() -> int:
    """How many CUDA devices Warp can run kernels on (0 without a usable driver)."""
    return init().get_cuda_device_count()


def warp_version() -> str:
    """Warp's version, for messages."""
    return wp.__version__


def device(torch_device: str | torch.device) -> str:
    """The Warp device name of a torch device (or of "cpu" / "cuda" / "cuda:N")."""
    text = str(torch_device)
    if text == "cuda":
        import torch

        text = f"cuda:{torch.cuda.current_device()}"
    return text


KERNEL_OPTIONS = {"fuse_fp": False, "enable_backward": False}
"""Warp's options for every kernel module of the package. No contraction into fused
multiply-adds: the float64 arithmetic then rounds as the numpy and torch code the kernels
replaced (the test oracles), and alike on the CPU and CUDA, where NVRTC would contract.
No adjoints: nothing is differentiated through Warp (the encoder's gradient is a kernel of
its own), and each kernel's generated adjoint would double the code to compile."""


def warp_module(name: str) -> str:
    """The Warp module that the kernels of this package's module ``name`` (``__name__`` of
    a module of ``kernels/``) are declared in, with ``KERNEL_OPTIONS``. Warp names a
    module's cache folder after it, so a name that followed the import path
    (``vdnif_addon.kernels.walk`` from the command line,
    ``bl_ext.user_default.vdnif_addon.kernels.walk`` in Blender) would compile every kernel
    again for each; this one depends only on the module's own name. The options are set
    here because ``wp.set_module_options`` without a module sets them on the caller's
    Python module, which holds none of these kernels."""
    module = f"vdnif.kernels.{name.rpartition('.')[2]}"
    wp.set_module_options(KERNEL_OPTIONS, module=module)
    return module


def load(module: ModuleType | str, device_name: str) -> None:
    """Compiles (first use on this machine) or loads the kernels of ``module`` for a device,
    saying on stderr when a compile takes a noticeable time. ``module`` is a Warp module's
    name (``warp_module``) or a Python module whose kernels Warp names after it."""
    init()
    name = module if isinstance(module, str) else module.__name__
    key = (name, device_name)
    if key in _loaded:
        return
    with _loading:              # Warp's concurrent CPU module loads can lose a kernel
        if key in _loaded:
            return
        start = time.perf_counter()
        with KernelCompile():               # the UI's progress line shows a long one
            wp.load_module(name, device=device_name)
        seconds = time.perf_counter() - start
        if seconds > 0.5:
            print(f"vdnif: compiled the '{name.rsplit('.', 1)[-1]}' kernels for {device_name} "
                  f"in {seconds:.1f} s (cached in {cache_dir()})", file=sys.stderr, flush=True)
        _loaded.add(key)


def kernel_modules() -> dict[str, str]:
    """The Warp module (``WARP_MODULE``) of every module of this package that declares
    kernels, by the module's own name (``walk``, ``render``, ...)."""
    package = __name__.rpartition(".")[0]
    found = {}
    for info in pkgutil.iter_modules(sys.modules[package].__path__):
        name = getattr(importlib.import_module(f"{package}.{info.name}"), "WARP_MODULE", None)
        if name is not None:
            found[info.name] = name
    return found


def load_all(device_name: str) -> float:
    """Compiles (first use on this machine) or loads every kernel module of the package for
    a device. What reports a speed calls it before its clock starts, so that a first run's
    compile is in no speed: the time is said apart, on stderr, when this call loaded any
    module. Returns the seconds."""
    start, loaded = time.perf_counter(), len(_loaded)
    for name in kernel_modules().values():
        load(name, device_name)
    seconds = time.perf_counter() - start
    if len(_loaded) > loaded:
        print(f"vdnif: kernels ready for {device_name} in {seconds:.1f} s (compiled, or loaded "
              f"from {cache_dir()}), apart from every speed reported", file=sys.stderr,
              flush=True)
    return seconds
