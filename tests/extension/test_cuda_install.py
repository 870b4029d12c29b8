"""The installer's torch build (``dependencies.torch_plan``), with the platform and the
driver given: PyPI's torch is a CPU build on Windows, so where a driver is present the CUDA
build comes from PyTorch's index, and without one the user is told that the CPU will be used."""

import sys

import pytest

from vdnif_addon import dependencies


def test_windows_with_an_nvidia_driver_installs_the_cuda_build():
    plan = dependencies.torch_plan("win32", driver=True)
    assert plan.cuda and plan.index == dependencies.TORCH_CUDA_INDEX
    assert "cu13" in plan.index, "Warp's wheels need a CUDA 13 driver: the same CUDA"
    command = dependencies.install_command("python.exe", "C:/vdnif/site-packages", plan)
    assert command[:3] == ["python.exe", "-m", "pip"]
    assert command[command.index("--extra-index-url") + 1] == dependencies.TORCH_CUDA_INDEX
    assert command[command.index("--target") + 1] == "C:/vdnif/site-packages"
    assert command[-2:] == [dependencies.WARP_REQUIREMENT, "torch"]


@pytest.mark.parametrize("platform", ["win32", "linux", "darwin"])
def test_without_a_driver_the_user_is_told_the_cpu_will_be_used(platform):
    plan = dependencies.torch_plan(platform, driver=False)
    assert not plan.cuda and plan.index is None
    assert plan.note.endswith("VDNIF will train and render on the CPU")
    assert "--extra-index-url" not in dependencies.install_command("python", "/x", plan)


def test_linux_takes_pypis_torch_which_brings_cuda():
    plan = dependencies.torch_plan("linux", driver=True)
    assert plan.cuda and plan.index is None and "CPU" not in plan.note


def test_the_driver_is_looked_for_when_not_given(monkeypatch):
    loaded = []

    def load(name):
        loaded.append(name)
        if name != "nvcuda.dll":
            raise OSError(name)

    monkeypatch.setattr(dependencies.ctypes, "CDLL", load)
    assert dependencies.torch_plan("win32").cuda and loaded == ["nvcuda.dll"]
    assert not dependencies.torch_plan("linux").cuda
    assert loaded[1:] == list(dependencies.DRIVER_LIBRARIES["linux"])
    assert not dependencies.nvidia_driver_present("darwin")
    assert dependencies.torch_plan().cuda == dependencies.nvidia_driver_present(sys.platform)
