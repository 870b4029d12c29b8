"""Warp's start-up as every command sees it: quiet on a machine without the NVIDIA driver,
standard error intact afterwards."""

import subprocess
import sys

import pytest
from conftest import REPO

from vdnif_addon.kernels import runtime


@pytest.mark.skipif(runtime.cuda_driver_present(), reason="this machine has a CUDA driver")
def test_no_cuda_warning_without_a_driver_and_stderr_still_works(tmp_path):
    code = ("import sys; from vdnif_addon.kernels import runtime; runtime.init(); "
            "print('after init', file=sys.stderr)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            cwd=REPO, timeout=120,
                            env={"VDNIF_KERNEL_CACHE": str(tmp_path), "PATH": "/usr/bin"})
    assert result.returncode == 0, result.stderr
    assert "CUDA" not in result.stderr and "after init" in result.stderr


def test_start_up_is_silenced_only_where_warp_has_no_cuda():
    """Standard error is silenced only when the driver does not load, and then Warp has no
    CUDA device either: no message a CUDA user needs is hidden."""
    wp = runtime.init()
    if not runtime.cuda_driver_present():
        assert not wp.is_cuda_available() and wp.get_cuda_device_count() == 0
