"""The installer's torch build (``dependencies.torch_plan``), with the platform and the
driver given: PyPI's torch is a CPU build on Windows, so where a driver is present the CUDA
build comes from PyTorch's index; PyPI's torch for Linux is the CUDA build, so without a driver
Linux and Windows take the CPU build from PyTorch's CPU index, and the user is told that the
CPU will be used. Afterwards the installer says what it installed and its size."""

import os
import pathlib
import sys

import pytest

from vdnif_addon import dependencies

REPO = pathlib.Path(__file__).resolve().parents[2]


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
    assert not plan.cuda and plan.index != dependencies.TORCH_CUDA_INDEX
    assert plan.note.endswith("VDNIF will train and render on the CPU")
    assert "CPU build" in plan.note


@pytest.mark.parametrize("platform", ["win32", "linux"])
def test_without_a_driver_linux_and_windows_take_the_cpu_build(platform):
    """PyPI's Linux torch is the CUDA build (gigabytes of CUDA libraries): the CPU build is
    asked for by its +cpu version from PyTorch's CPU index, which nothing else has, so pip
    cannot fall back to the CUDA build; Warp still comes from PyPI."""
    plan = dependencies.torch_plan(platform, driver=False)
    command = dependencies.install_command("python", "/x", plan)
    assert command[command.index("--extra-index-url") + 1] == dependencies.TORCH_CPU_INDEX
    assert dependencies.TORCH_CPU_INDEX == "https://download.pytorch.org/whl/cpu"
    assert command.count("--extra-index-url") == 1 and "--index-url" not in command
    assert command[-2:] == [dependencies.WARP_REQUIREMENT,
                            f"torch=={dependencies.TORCH_VERSION}+cpu"]


def test_macos_takes_pypis_torch_which_has_no_cuda():
    plan = dependencies.torch_plan("darwin", driver=False)
    command = dependencies.install_command("python", "/x", plan)
    assert plan.index is None and "--extra-index-url" not in command
    assert command[-1] == "torch" and plan.note.startswith("macOS has no CUDA")


def test_the_cpu_build_is_the_pinned_torch_release():
    pinned = [line.strip() for line in (REPO / "requirements.txt").read_text().splitlines()
              if line.startswith("torch==")]
    assert pinned == [f"torch=={dependencies.TORCH_VERSION}"]


def test_linux_takes_pypis_torch_which_brings_cuda():
    plan = dependencies.torch_plan("linux", driver=True)
    assert plan.cuda and plan.index is None and "CPU" not in plan.note
    assert dependencies.install_command("python", "/x", plan)[-1] == "torch"


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


def fake_install(folder, name, version, sizes):
    """A distribution as pip --target leaves it: its files and a dist-info whose RECORD
    lists them (and itself)."""
    info = folder / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    rows = [f"{info.name}/METADATA,,", f"{info.name}/RECORD,,"]
    for index, size in enumerate(sizes):
        path = folder / name.replace("-", "_") / f"part{index}.bin"
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(b"\0" * size)
        rows.append(f"{path.relative_to(folder).as_posix()},,{size}")
    (info / "RECORD").write_text("\n".join(rows) + "\n")
    return sum(sizes) + sum(os.path.getsize(info / part) for part in ("METADATA", "RECORD"))


def test_the_installer_says_what_it_installed_and_its_size(tmp_path):
    torch = fake_install(tmp_path, "torch", "2.13.0+cpu", [2_000_000, 1_400_000])
    warp = fake_install(tmp_path, "warp-lang", "1.19.0", [600_000])
    other = fake_install(tmp_path, "sympy", "1.14.0", [1_000_000])
    rows = dependencies.installed(str(tmp_path))
    assert rows == [("torch", "2.13.0+cpu", torch), ("sympy", "1.14.0", other),
                    ("warp-lang", "1.19.0", warp)]
    plan = dependencies.torch_plan("linux", driver=False)
    assert dependencies.installed_line(str(tmp_path), plan) == (
        f"Installed PyTorch 2.13.0+cpu (CPU build, 3 MB) and Warp 1.19.0 (1 MB): 5 MB with "
        f"their dependencies in {tmp_path}")
    cuda = dependencies.torch_plan("win32", driver=True)
    assert "(CUDA build, 3 MB)" in dependencies.installed_line(str(tmp_path), cuda)
