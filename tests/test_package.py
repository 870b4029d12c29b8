"""`make package`: the manifest follows the extension rules; the zip leaves dev files out."""

import sys
import tomllib
import zipfile

import pytest
from conftest import REPO

sys.path.insert(0, str(REPO / "tools"))
import package  # noqa: E402


def test_zip_holds_the_extension_and_no_dev_files(tmp_path):
    target = package.build(REPO, tmp_path)
    names = zipfile.ZipFile(target).namelist()
    assert target.name == "vdnif-0.1.0.zip"
    for needed in ("blender_manifest.toml", "__init__.py", "vdnif_addon/batch.py",
                   "vdnif_addon/blender/capture_scene.py", "operators/__init__.py",
                   "assets/meshes/spot.obj", "assets/meshes/README.md"):
        assert needed in names
    for name in names:
        assert not name.startswith(("tests/", ".venv/", ".git/", "tools/", ".ci/",
                                    ".kernel-cache/", "pyproject.toml"))
        assert "__pycache__" not in name and not name.endswith(".pyc")


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
])
def test_exclude_patterns_follow_gitignore_rules(path, expected):
    patterns = tomllib.loads((REPO / "blender_manifest.toml").read_text())["build"][
        "paths_exclude_pattern"]
    assert package.excluded(path, patterns) is expected
