"""Which PyTorch build the extension's installer takes, and what the user is told of it.

PyPI's torch for Windows is a CPU-only build: where an NVIDIA driver is present the installer
takes PyTorch's CUDA build from PyTorch's own package index instead. PyPI's torch for Linux is
the CUDA build (gigabytes of CUDA libraries): without a driver, on Linux and Windows, the
installer takes PyTorch's CPU build from PyTorch's CPU index (a few hundred MB) and says
plainly that VDNIF will train and render on the CPU. Afterwards it says what it installed and
its size on disk. Imports neither torch nor Warp (it runs before they are installed).
"""

from __future__ import annotations

import ctypes
import importlib.metadata
import os
import re
import sys
from dataclasses import dataclass

WARP_REQUIREMENT = "warp-lang==1.19.0"
"""The Warp release the kernels are written and tested for (as pinned in requirements.txt)."""

TORCH_VERSION = "2.13.0"
"""The PyTorch release the CPU build is pinned to (as pinned in requirements.txt): a CPU build's
version carries the ``+cpu`` tag, which exists only on PyTorch's CPU index."""

TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
"""PyTorch's package index of its CPU builds (Linux and Windows)."""

TORCH_CUDA_INDEX = "https://download.pytorch.org/whl/cu130"
"""PyTorch's package index of its CUDA 13 builds: the CUDA that Warp's wheels need too, so
one driver serves both."""

DRIVER_LIBRARIES = {"win32": ("nvcuda.dll",), "linux": ("libcuda.so.1", "libcuda.so")}
"""The NVIDIA driver's CUDA library per platform (none on macOS, which has no CUDA)."""


def nvidia_driver_present(platform: str = sys.platform) -> bool:
    """Whether the NVIDIA driver's CUDA library can be loaded here."""
    for name in DRIVER_LIBRARIES.get(platform, ()):
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


@dataclass(frozen=True)
class TorchPlan:
    """Where torch comes from (``index``: an extra package index, None for PyPI's alone),
    whether it can use the GPU, and the line that tells the user so."""

    index: str | None
    cuda: bool
    note: str
    requirement: str = "torch"          # what pip is asked for


def torch_plan(platform: str = sys.platform, driver: bool | None = None) -> TorchPlan:
    """The torch build for ``platform`` (``sys.platform``) with or without an NVIDIA
    ``driver`` (None: looked for)."""
    if driver is None:
        driver = nvidia_driver_present(platform)
    if not driver:
        note = "PyTorch's CPU build, VDNIF will train and render on the CPU"
        if platform == "darwin":             # PyPI's macOS torch has no CUDA in it
            return TorchPlan(None, False, f"macOS has no CUDA: {note}")
        return TorchPlan(TORCH_CPU_INDEX, False, f"no NVIDIA driver found: {note}",
                         f"torch=={TORCH_VERSION}+cpu")
    if platform == "win32":
        return TorchPlan(TORCH_CUDA_INDEX, True, "NVIDIA driver found: PyTorch's CUDA 13 "
                                                 "build from download.pytorch.org")
    return TorchPlan(None, True, "NVIDIA driver found: PyPI's PyTorch, built with CUDA")


def install_command(python: str, folder: str, plan: TorchPlan) -> list[str]:
    """pip installing Warp and ``plan``'s torch into ``folder`` with the interpreter
    ``python`` (Blender's own). An extra index's torch wins over PyPI's of the same release:
    its version carries the CUDA tag (``+cu130``), which pip ranks higher; the CPU build is
    asked for by its ``+cpu`` version, which only PyTorch's CPU index has (Warp and torch's
    own dependencies still come from PyPI)."""
    index = ["--extra-index-url", plan.index] if plan.index else []
    return [python, "-m", "pip", "install", "--upgrade", "--no-input", "--target", folder,
            *index, WARP_REQUIREMENT, plan.requirement]


def installed(folder: str) -> list[tuple[str, str, int]]:
    """(name, version, bytes on disk) of every distribution pip installed into ``folder``
    (its ``*.dist-info`` records; the name lower case with dashes), largest first."""
    found = []
    for dist in importlib.metadata.distributions(path=[folder]):
        size = 0
        for file in dist.files or ():
            path = os.path.join(folder, file)
            if os.path.isfile(path):
                size += os.path.getsize(path)
        name = re.sub(r"[-_.]+", "-", dist.name).lower()    # as pip compares
        found.append((name, dist.version, size))
    return sorted(found, key=lambda row: -row[2])


def installed_line(folder: str, plan: TorchPlan | None) -> str:
    """What the installer says it installed: PyTorch (which build) and Warp with their
    versions and sizes in ``folder``, and the folder's size with their dependencies. A
    package pip left out of ``folder`` (found elsewhere on the path) is named by the version
    that imports, without a size."""
    found = {name: (version, size) for name, version, size in installed(folder)}

    def described(name: str, title: str, build: str | None = None) -> str:
        if name in found:
            version, size = found[name]
        else:
            try:
                version, size = importlib.metadata.version(name), None
            except importlib.metadata.PackageNotFoundError:
                version, size = "?", None
        details = ", ".join(text for text in (build, size is not None and _megabytes(size))
                            if text)
        return f"{title} {version}" + (f" ({details})" if details else "")

    build = None if plan is None else "CUDA build" if plan.cuda else "CPU build"
    total = sum(size for _, size in found.values())
    return (f"Installed {described('torch', 'PyTorch', build)} and "
            f"{described('warp-lang', 'Warp')}: {_megabytes(total)} with their dependencies "
            f"in {folder}")


def _megabytes(size: int) -> str:
    return f"{size / 1e6:,.0f} MB"
