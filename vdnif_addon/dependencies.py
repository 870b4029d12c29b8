"""Which PyTorch build the extension's installer takes, and what the user is told of it.

PyPI's torch for Windows is a CPU-only build: where an NVIDIA driver is present the installer
takes PyTorch's CUDA build from PyTorch's own package index instead; elsewhere it says
plainly that VDNIF will train and render on the CPU. Imports neither torch nor Warp (it runs
before they are installed).
"""

from __future__ import annotations

import ctypes
import sys
from dataclasses import dataclass

WARP_REQUIREMENT = "warp-lang==1.19.0"
"""The Warp release the kernels are written and tested for (as pinned in requirements.txt)."""

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


def torch_plan(platform: str = sys.platform, driver: bool | None = None) -> TorchPlan:
    """The torch build for ``platform`` (``sys.platform``) with or without an NVIDIA
    ``driver`` (None: looked for)."""
    if driver is None:
        driver = nvidia_driver_present(platform)
    if not driver:
        where = "macOS has no CUDA" if platform == "darwin" else "no NVIDIA driver found"
        return TorchPlan(None, False, f"{where}: PyTorch's CPU build, VDNIF will train and "
                                      "render on the CPU")
    if platform == "win32":
        return TorchPlan(TORCH_CUDA_INDEX, True, "NVIDIA driver found: PyTorch's CUDA 13 "
                                                 "build from download.pytorch.org")
    return TorchPlan(None, True, "NVIDIA driver found: PyPI's PyTorch, built with CUDA")


def install_command(python: str, folder: str, plan: TorchPlan) -> list[str]:
    """pip installing Warp and ``plan``'s torch into ``folder`` with the interpreter
    ``python`` (Blender's own). An extra index's torch wins over PyPI's of the same release:
    its version carries the CUDA tag (``+cu130``), which pip ranks higher."""
    index = ["--extra-index-url", plan.index] if plan.index else []
    return [python, "-m", "pip", "install", "--upgrade", "--no-input", "--target", folder,
            *index, WARP_REQUIREMENT, "torch"]
