"""Warp's start-up as every command sees it: quiet on a machine without the NVIDIA driver,
standard error intact afterwards."""

import os
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


# Imports the core under the module name argv[1] (its parent packages made empty, as
# Blender's bl_ext.<repository> are to the extension) and loads one kernel module on the CPU.
IMPORT_AS = """
import importlib, importlib.util, pathlib, sys, types
name, root = sys.argv[1], pathlib.Path(sys.argv[2])
parts = name.split(".")
for end in range(1, len(parts)):
    sys.modules[".".join(parts[:end])] = types.ModuleType(".".join(parts[:end]))
spec = importlib.util.spec_from_file_location(name, root / "__init__.py",
                                              submodule_search_locations=[str(root)])
sys.modules[name] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sys.modules[name])
cast = importlib.import_module(name + ".kernels.cast")
importlib.import_module(name + ".kernels.runtime").load(cast.WARP_MODULE, "cpu")
print(cast._first_hits.module.name)
"""


@pytest.mark.slow
def test_the_kernel_cache_serves_every_import_path(tmp_path):
    """The command line imports the core as ``vdnif_addon``, Blender as
    ``bl_ext.user_default.vdnif_addon``: the second, on the same cache, compiles nothing
    (Warp writes each compiled module's files into the cache as it builds it)."""
    def cached_files():
        return sorted(path.relative_to(tmp_path) for path in tmp_path.rglob("*")
                      if path.is_file())

    environment = dict(os.environ, VDNIF_KERNEL_CACHE=str(tmp_path))
    seen = []
    for name in ("vdnif_addon", "bl_ext.user_default.vdnif_addon"):
        result = subprocess.run([sys.executable, "-c", IMPORT_AS, name,
                                 str(REPO / "vdnif_addon")], capture_output=True, text=True,
                                cwd=tmp_path, env=environment, timeout=300)
        assert result.returncode == 0, result.stderr
        seen.append((result.stdout.strip(), cached_files()))
    (first_module, first_files), (second_module, second_files) = seen
    assert any(path.suffix == ".o" for path in first_files)      # the first one compiled
    assert second_files == first_files
    assert first_module == second_module == "vdnif.kernels.cast"


def declared_kernels():
    """(Python module, Warp kernel) of every kernel declared in a module of kernels/."""
    import importlib
    import pkgutil

    import warp as wp

    from vdnif_addon import kernels

    for info in pkgutil.iter_modules(kernels.__path__):
        module = importlib.import_module(f"{kernels.__name__}.{info.name}")
        for value in vars(module).values():
            if isinstance(value, wp.Kernel) and value.func.__module__ == module.__name__:
                yield module, value


def test_every_kernel_lives_in_a_warp_module_named_apart_from_the_import_path():
    """What the cache test checks for one module, for all of them: each kernel of the core
    is declared in its module's fixed Warp module."""
    found = {(module.__name__, kernel.key): (kernel.module.name,
                                             runtime.warp_module(module.__name__))
             for module, kernel in declared_kernels()}
    assert len(found) >= 20
    assert {key: names[0] for key, names in found.items()} == {
        key: names[1] for key, names in found.items()}
    assert all(names[0].startswith("vdnif.kernels.") for names in found.values())


def test_load_all_loads_every_kernel_module_once_and_times_it(monkeypatch, capsys):
    """Every module of kernels/ that declares kernels is loaded, the time said on stderr;
    a second call finds them loaded, takes no time and says nothing. Warp's loading is a
    stand-in that takes 0.1 s per module."""
    import importlib
    import pkgutil
    import time

    import warp as wp

    from vdnif_addon import kernels

    declared = {importlib.import_module(f"{kernels.__name__}.{info.name}").WARP_MODULE
                for info in pkgutil.iter_modules(kernels.__path__)
                if hasattr(importlib.import_module(f"{kernels.__name__}.{info.name}"),
                           "WARP_MODULE")}
    loaded = []
    monkeypatch.setattr(wp, "load_module", lambda name, device: (
        loaded.append((name, device)), time.sleep(0.1)))
    monkeypatch.setattr(runtime, "_loaded", set())
    seconds = runtime.load_all("cpu")
    assert sorted(loaded) == sorted((name, "cpu") for name in declared)
    assert len(declared) >= 7 and seconds >= 0.1 * len(declared)
    assert f"kernels ready for cpu in {seconds:.1f} s" in capsys.readouterr().err
    assert runtime.load_all("cpu") < 0.1 and len(loaded) == len(declared)
    assert capsys.readouterr().err == ""


def test_every_kernel_module_compiles_without_contraction_or_adjoints():
    """Every Warp module the core declares kernels in has ``KERNEL_OPTIONS``: the options
    must reach the module the kernels are in, not the Python module that names it."""
    options = {kernel.module.name: {key: kernel.module.options[key]
                                    for key in runtime.KERNEL_OPTIONS}
               for _, kernel in declared_kernels()}
    assert len(options) >= 6
    assert options == {name: runtime.KERNEL_OPTIONS for name in options}


NO_NVRTC = pytest.mark.skipif(sys.platform == "darwin",
                              reason="Warp has no CUDA compiler on macOS")


@NO_NVRTC
def test_a_kernel_module_keeps_multiply_and_add_apart_on_cuda(tmp_path):
    """NVRTC contracts ``a * b + c`` into one fused multiply-add, which rounds once where
    the numpy oracles round twice; a module named by ``warp_module`` keeps them apart. The
    PTX for sm_90 of the same kernel in a module with Warp's defaults has the fused form,
    so the check can fail. Needs Warp's NVRTC (not on macOS), not a GPU."""
    import warp as wp

    runtime.init()
    ptx = {}
    for name in (runtime.warp_module("probe_contraction"), "vdnif_test_probe_defaults"):
        @wp.kernel(module=name)
        def multiply_add(a: wp.array(dtype=wp.float64), b: wp.array(dtype=wp.float64),
                         out: wp.array(dtype=wp.float64)):
            i = wp.tid()
            out[i] = a[i] * b[i] + out[i]

        folder = tmp_path / name
        wp.compile_aot_module(name, arch=90, module_dir=folder, use_ptx=True)
        ptx[name] = "".join(path.read_text() for path in folder.glob("*.ptx"))
    ours, defaults = ptx.values()
    assert "fma.rn.f64" in defaults
    assert "fma.rn.f64" not in ours and "mul.rn.f64" in ours


@NO_NVRTC
def test_every_kernel_module_compiles_to_ptx_without_a_gpu(tmp_path):
    """Each kernel module of the core compiles for CUDA (sm_75, the oldest architecture
    Warp's CUDA 13 targets) through Warp's NVRTC, here where no GPU is: a CUDA-only error
    in a kernel's source is caught before a GPU session runs it. The walk's float64 holds
    no fused multiply-add there."""
    import warp as wp

    runtime.init()
    compiled = {}
    for short, name in runtime.kernel_modules().items():
        folder = tmp_path / short
        wp.compile_aot_module(name, arch=75, module_dir=folder, use_ptx=True)
        compiled[short] = "".join(path.read_text() for path in folder.glob("*.ptx"))
    assert {"walk", "render", "encoder", "dda", "cast", "surface", "cells"} <= set(compiled)
    assert all(".entry" in ptx for ptx in compiled.values())
    assert "fma.rn.f64" not in compiled["walk"] and "mul.rn.f64" in compiled["walk"]
