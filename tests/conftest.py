"""Test harness: pure-core tests run without bpy; Blender tests load the package as a real
extension (``bl_ext.dev.vdnif``) with user resources in a temporary folder and an empty scene
per test (how an extension loads: Blender's manual, *Extensions*; ``bl_ext.<repo>.<id>``
is the module name Blender gives an extension of a user repository)."""

import ast
import atexit
import functools
import importlib
import os
import pathlib
import shutil
import sys
import tempfile
import types

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
EXTENSION_MODULE = "bl_ext.dev.vdnif"
# The start of a script that enables the extension from this source tree in a fresh process
# (``python -c``), with user resources in a temporary folder: tests append their checks.
ENABLE_IN_FRESH_PROCESS = f"""
import atexit, os, shutil, sys, tempfile
os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="vdnif-user-")
folder = tempfile.mkdtemp(prefix="vdnif-repo-")
atexit.register(shutil.rmtree, os.environ["BLENDER_USER_RESOURCES"], True)
atexit.register(shutil.rmtree, folder, True)  # unlinks the symlink, never follows it
import bpy, addon_utils
os.symlink({str(REPO)!r}, os.path.join(folder, "vdnif"))
bpy.context.preferences.extensions.repos.new(name="dev", module="dev",
                                             custom_directory=folder, source="USER")
addon_utils.enable("{EXTENSION_MODULE}", default_set=True, handle_error=print)
"""

# Must be set before bpy is first imported, so user preferences never touch the real home;
# removed when the test process exits (every run left one behind in /tmp before).
os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="vdnif-user-")
atexit.register(shutil.rmtree, os.environ["BLENDER_USER_RESOURCES"], True)
# Compiled kernels are cached inside the checkout (ignored by git), not in the user's home.
os.environ.setdefault("VDNIF_KERNEL_CACHE", str(REPO / ".kernel-cache"))

# The suite's exit status, kept for ``pytest_unconfigure``.
_SESSION_STATUS: list[int] = []


def pytest_sessionfinish(session, exitstatus):
    _SESSION_STATUS.append(int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """Ends a suite that imported bpy once every report is out, as ``batch.py`` ends a
    command: the exit handlers run, then ``os._exit`` skips the C++ static destructors.
    bpy 4.5's audio ``GlobalState`` destructor destroys a condition variable that its own
    delayed-close thread still waits on whenever the bpy module outlives interpreter
    teardown, and glibc then waits forever: the whole suite passed and its process never
    ended."""
    if not _SESSION_STATUS or "bpy" not in sys.modules:
        return
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(_SESSION_STATUS[-1])


@pytest.fixture(scope="session")
def extension():
    """The extension enabled the way Blender enables it, from this source tree."""
    import bpy  # first: it puts Blender's script modules (addon_utils) on sys.path

    # isort: split
    import addon_utils

    repo_dir = tempfile.mkdtemp(prefix="vdnif-repo-")
    atexit.register(shutil.rmtree, repo_dir, True)  # unlinks the symlink, never follows it
    os.symlink(REPO, os.path.join(repo_dir, "vdnif"))
    bpy.context.preferences.extensions.repos.new(
        name="dev", module="dev", custom_directory=repo_dir, source="USER")
    addon_utils.enable(EXTENSION_MODULE, default_set=True, handle_error=_raise)
    yield importlib.import_module(EXTENSION_MODULE)
    addon_utils.disable(EXTENSION_MODULE, default_set=True)


def _raise(exc):
    raise exc


@pytest.fixture
def core(extension):
    """Imports a core module as the extension sees it: ``core("blender.capture_scene")``."""
    return lambda name: importlib.import_module(f"{EXTENSION_MODULE}.vdnif_addon.{name}")


@pytest.fixture
def empty_scene(extension):
    """An empty scene with the extension still enabled."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


@functools.cache
def extension_oracle(name):
    """The oracle ``tests/oracles/NAME.py`` bound to the extension's copy of the core (its
    ``from vdnif_addon.X import`` read as ``from bl_ext.dev.vdnif.vdnif_addon.X import``),
    so a Blender test keeps to that one identity (tests/project/test_module_identity.py). Call it
    from a test that has the extension enabled."""
    path = REPO / "tests" / "oracles" / f"{name}.py"
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            tops = {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            tops = {(node.module or "").split(".")[0] if not node.level else "."}
        else:
            continue
        if tops & {"oracles", "."} or (isinstance(node, ast.Import) and "vdnif_addon" in tops):
            raise ImportError(f"oracle {name} line {node.lineno}: only 'from vdnif_addon.X "
                              "import' statements are bound to the extension")
        if "vdnif_addon" in tops:
            node.module = f"{EXTENSION_MODULE}.{node.module}"
    module = types.ModuleType(f"extension_oracles.{name}")
    module.__file__ = str(path)
    sys.modules[module.__name__] = module      # classes find their module while it runs
    exec(compile(tree, str(path), "exec"), module.__dict__)
    return module
