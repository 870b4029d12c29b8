"""`make package`: the manifest follows the extension rules; the zip leaves dev files and the
studies out, and what it holds runs without them; packaging needs the standard library only."""

import ast
import os
import re
import subprocess
import sys
import tomllib
import zipfile

import pytest
from conftest import REPO

sys.path.insert(0, str(REPO / "tools"))
import package  # noqa: E402

STUDY_COMMANDS = ("demo", "experiment", "bench", "side-by-side", "bench-network")


@pytest.fixture(scope="module")
def zip_names(tmp_path_factory):
    target = package.build(REPO, tmp_path_factory.mktemp("zip"))
    assert target.name == "vdnif-0.1.0.zip"
    return zipfile.ZipFile(target).namelist()


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The zip's content unpacked, as Blender installs it."""
    folder = tmp_path_factory.mktemp("installed")
    zipfile.ZipFile(package.build(REPO, folder / "build")).extractall(folder / "vdnif")
    return folder / "vdnif"


def test_zip_holds_the_extension_and_no_dev_files(zip_names):
    for needed in ("blender_manifest.toml", "__init__.py", "vdnif_addon/batch.py",
                   "vdnif_addon/settings.py", "vdnif_addon/cli/__init__.py",
                   "vdnif_addon/cli/pipeline.py", "vdnif_addon/cli/options.py",
                   "vdnif_addon/blender/capture_scene.py", "vdnif_addon/inference/metrics.py",
                   "vdnif_addon/training/train.py", "vdnif_addon/kernels/encoder.py",
                   "operators/__init__.py", "panels/sidebar.py", "vdnif_addon/presets.json",
                   "assets/meshes/spot.obj", "assets/meshes/README.md"):
        assert needed in zip_names
    for name in zip_names:
        assert not name.startswith(("tests/", ".venv/", ".git/", "tools/", ".ci/", "docs/",
                                    ".kernel-cache/", "pyproject.toml", "build/", "out/",
                                    "vdnif_addon/studies/", "vdnif_addon/cli/studies.py"))
        assert name.split("/")[0] not in (".git", ".gitignore", "Makefile", "pytest.ini",
                                          "requirements.txt")
        assert "__pycache__" not in name and not name.endswith(".pyc")


def _module(name):
    """The dotted module of a .py path in the zip ("" for the root __init__)."""
    parts = name[:-len(".py")].split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_shipped_module_imports_what_the_zip_leaves_out(zip_names):
    """Every import of the core, those inside functions too, names a module the zip holds;
    the one exception is an import under ``if ... find_spec(...)``, which checks first."""
    shipped = {_module(n) for n in zip_names if n.endswith(".py")}
    source = {_module(p.relative_to(REPO).as_posix())
              for p in [*REPO.glob("*.py"), *(REPO / "vdnif_addon").rglob("*.py")]}
    assert {"vdnif_addon.studies", "vdnif_addon.cli.studies"} <= source - shipped
    broken = []
    for name in sorted(n for n in zip_names if n.endswith(".py")):
        module = _module(name)
        package_name = module if name.endswith("__init__.py") else module.rpartition(".")[0]
        tree = ast.parse((REPO / name).read_text())
        guarded = {id(inner) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and "find_spec" in ast.unparse(node.test)
                   for statement in node.body for inner in ast.walk(statement)}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and id(node) not in guarded:
                base = node.module or ""
                if node.level:
                    parts = [part for part in package_name.split(".") if part]
                    base = ".".join([*parts[:len(parts) - node.level + 1], *([base] if base
                                                                            else [])])
                targets = {f"{base}.{alias.name}" for alias in node.names} | {base}
            elif isinstance(node, ast.Import) and id(node) not in guarded:
                targets = [alias.name for alias in node.names]
            else:
                continue
            for target in targets:
                while target and target not in source:
                    target = target.rpartition(".")[0]
                if target and target not in shipped:
                    broken.append(f"{name}:{node.lineno} imports {target}")
    assert not broken, broken


def _batch(installed, *argv):
    run = subprocess.run([sys.executable, str(installed / "vdnif_addon" / "batch.py"), "--",
                          *argv], capture_output=True, text=True, timeout=300,
                         cwd=installed.parent, env={**os.environ, "COLUMNS": "200"})
    return run.returncode, run.stdout, run.stderr


@pytest.mark.parametrize("command, extra", [
    ("demo", []), ("experiment", ["static", "--quick"]), ("bench", ["--help"]),
    ("side-by-side", ["--scene", "bunny"]), ("bench-network", ["-h"])])
def test_installed_extension_refuses_the_studies_in_one_line(installed, command, extra):
    code, out, err = _batch(installed, command, *extra)
    assert code == 1 and out == ""
    assert err.splitlines() == [f"vdnif: error: '{command}' is a developer study: it needs "
                                "the repository checkout (the installed extension leaves the "
                                "studies out)"]


def test_installed_extension_lists_the_studies_as_such_and_runs_the_rest(installed):
    assert not (installed / "vdnif_addon" / "studies").exists()
    code, out, err = _batch(installed, "--help")
    assert code == 0, err
    for command in STUDY_COMMANDS:
        assert re.search(rf"^ +{command}\s+developer study: needs the repository checkout$",
                         out, re.M), out
    code, out, err = _batch(installed, "evaluate", "--help")
    assert code == 0 and "--model" in out, err
    code, out, err = _batch(installed, "evaluate", "--model", "missing.vdnif")
    assert code == 1 and err.count("\n") == 1 and "missing.vdnif" in err, err


def test_the_study_commands_are_those_the_studies_add():
    import argparse

    import bpy  # noqa: F401  (before the parser's blender adapters)

    from vdnif_addon import cli
    from vdnif_addon.cli import studies

    assert cli.studies is studies and cli.STUDY_COMMANDS == STUDY_COMMANDS
    commands = argparse.ArgumentParser().add_subparsers()
    studies.add_commands(commands)
    assert tuple(commands.choices) == STUDY_COMMANDS


def test_packaging_needs_the_standard_library_only(tmp_path):
    """``-S -I``: no site-packages, so any third-party import fails the run."""
    run = subprocess.run([sys.executable, "-S", "-I", str(REPO / "tools" / "package.py"),
                          "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "vdnif-0.1.0.zip").is_file()


def test_make_package_installs_nothing(tmp_path):
    """The package target does not build the venv, even where there is none."""
    run = subprocess.run(["make", "-n", "package", f"VENV={tmp_path / 'none'}"], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert "tools/package.py" in run.stdout
    assert "pip" not in run.stdout and "venv" not in run.stdout and str(tmp_path) not in \
        run.stdout


def test_manifest_is_valid_and_versions_agree():
    import vdnif_addon

    manifest = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    package.validate_manifest(manifest)
    assert manifest["version"] == vdnif_addon.__version__


@pytest.mark.parametrize("change, message", [
    ({"tagline": "x" * 65}, "at most 64"),
    ({"tagline": "Ends with a dot."}, "punctuation"),
    ({"version": "1.0"}, "semantic version"),
    ({"blender_version_min": "4.1.0"}, "4.2.0 or later"),
    ({"type": "theme"}, "add-on"),
    ({"license": "GPL"}, "SPDX"),
    ({"maintainer": ""}, "'maintainer' is empty"),
    ({"id": None}, "'id' is required"),
])
def test_broken_manifests_are_refused(change, message):
    manifest = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    for key, value in change.items():
        if value is None:
            del manifest[key]
        else:
            manifest[key] = value
    with pytest.raises(package.ManifestError, match=message):
        package.validate_manifest(manifest)


@pytest.mark.parametrize("path, expected", [
    ("tests/test_x.py", True), ("vdnif_addon/__pycache__/a.pyc", True),
    ("vdnif_addon/tests.py", False), ("deep/build/x", False), ("build/x", True),
    ("Makefile", True), ("vdnif_addon/cli/__init__.py", False),
    (".git", True), (".git/HEAD", True), (".github/x", True),     # a worktree's .git is a file
    ("vdnif_addon/studies/bench.py", True), ("vdnif_addon/cli/studies.py", True),
    ("vdnif_addon/cli/pipeline.py", False),
])
def test_exclude_patterns_follow_gitignore_rules(path, expected):
    patterns = tomllib.loads((REPO / "blender_manifest.toml").read_text())["build"][
        "paths_exclude_pattern"]
    assert package.excluded(path, patterns) is expected
