"""Builds the installable extension zip and validates blender_manifest.toml.

Stands in for ``blender --command extension build``, which needs a Blender executable: the
manifest is checked against the rules of Blender's extension manifest (the Blender manual,
*Extensions > How to Create Extensions*; the cases of tests/extension/test_package.py) and
the ``[build] paths_exclude_pattern`` list is applied with gitignore-style matching. The
studies and the dev tools stay out of the zip. It imports the standard library only, so
that ``make package`` runs with a bare Python 3.11 and installs nothing.

    python tools/package.py --out build
"""

import argparse
import fnmatch
import os
import pathlib
import re
import sys
import tomllib
import zipfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
            "blender_version_min", "license")
SEMVER = re.compile(r"^\d+\.\d+\.\d+(?:-[0-9A-Za-z.-]+)?(?:\+[0-9A-Za-z.-]+)?$")


class ManifestError(Exception):
    pass


def validate_manifest(manifest):
    """Raises ManifestError naming the first field that breaks the extension rules."""
    for key in REQUIRED:
        if key not in manifest:
            raise ManifestError(f"manifest: '{key}' is required")
    for key, value in manifest.items():
        if value in ("", [], {}):
            raise ManifestError(f"manifest: '{key}' is empty")
    if manifest["schema_version"] != "1.0.0":
        raise ManifestError("manifest: schema_version must be \"1.0.0\"")
    if not re.fullmatch(r"[a-z][a-z0-9_]*", manifest["id"]):
        raise ManifestError(f"manifest: id '{manifest['id']}' must be a lowercase identifier")
    for key in ("version", "blender_version_min"):
        if not SEMVER.match(str(manifest[key])):
            raise ManifestError(f"manifest: {key} '{manifest[key]}' is not a semantic version")
    tagline = manifest["tagline"]
    if len(tagline) > 64:
        raise ManifestError(f"manifest: tagline is {len(tagline)} characters, at most 64")
    if tagline[-1] in ".,;:!?":
        raise ManifestError("manifest: tagline must not end with punctuation")
    if manifest["type"] != "add-on":
        raise ManifestError(f"manifest: type '{manifest['type']}' is not \"add-on\"")
    if _version_tuple(manifest["blender_version_min"]) < (4, 2, 0):
        raise ManifestError("manifest: blender_version_min must be 4.2.0 or later")
    licenses = manifest["license"]
    if not isinstance(licenses, list) or not all(
            isinstance(v, str) and v.startswith("SPDX:") for v in licenses):
        raise ManifestError("manifest: license must be a list of \"SPDX:...\" identifiers")
    patterns = manifest.get("build", {}).get("paths_exclude_pattern", [])
    if not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
        raise ManifestError("manifest: build.paths_exclude_pattern must be a list of strings")


def _version_tuple(text):
    return tuple(int(part) for part in str(text).split("-")[0].split(".")[:3])


def excluded(relative, patterns, is_dir=False):
    """gitignore-style match of a POSIX path relative to the root: '/x' is anchored at the
    root, a trailing '/' matches a directory and everything in it, '*' globs a name."""
    parts = relative.split("/")
    for pattern in patterns:
        anchored = pattern.startswith("/")
        directory = pattern.endswith("/")
        body = pattern.strip("/")
        prefixes = ["/".join(parts[:i]) for i in range(1, len(parts) + 1)]
        if directory and not is_dir:
            prefixes = prefixes[:-1]
        for prefix in prefixes:
            name = prefix if anchored or "/" in body else prefix.rsplit("/", 1)[-1]
            if fnmatch.fnmatchcase(name, body):
                return True
    return False


def package_files(root, patterns):
    """Sorted POSIX paths under ``root`` that go into the package."""
    files = []
    for folder, subfolders, names in os.walk(root):
        base = pathlib.Path(folder).relative_to(root).as_posix()
        prefix = "" if base == "." else base + "/"
        subfolders[:] = [d for d in subfolders if not excluded(prefix + d, patterns, is_dir=True)]
        files += [prefix + n for n in names if not excluded(prefix + n, patterns)]
    return sorted(files)


def build(root, out_dir):
    """Validates the manifest and writes ``<id>-<version>.zip`` into ``out_dir``."""
    manifest = tomllib.loads((root / "blender_manifest.toml").read_text())
    validate_manifest(manifest)
    patterns = manifest.get("build", {}).get("paths_exclude_pattern", [])
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{manifest['id']}-{manifest['version']}.zip"
    out_relative = out_dir.resolve()
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as archive:
        for relative in package_files(root, patterns):
            if (root / relative).resolve().is_relative_to(out_relative):
                continue
            archive.write(root / relative, relative)
    return target


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "build")
    args = parser.parse_args(argv)
    try:
        target = build(ROOT, args.out)
    except (ManifestError, tomllib.TOMLDecodeError) as exc:
        print(f"package: error: {exc}", file=sys.stderr)
        return 1
    with zipfile.ZipFile(target) as archive:
        count = len(archive.namelist())
    print(f"wrote {target} ({count} files, {target.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
