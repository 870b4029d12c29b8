"""A mesh file and every file it names checked before an importer sees them (plain Python:
no bpy, numpy or torch).

Blender's importers open the files a mesh file names by themselves: an OBJ's material
libraries (``mtllib``) and their textures (``map_Kd`` ...), a glTF's buffers and images. A
FIFO among them blocks the importer forever, a device such as /dev/zero is read until memory
runs out. So each is checked like the files VDNIF opens (``safe_io.check_input_file``: a
regular file of at most ``limits.MAX_INPUT_FILE_BYTES``) when it exists; a missing one is
left to the importer, which warns and goes on. A name that cannot be resolved to one file
(an MTL texture line's options) is checked under each reading.

The counts in a mesh file's header are bounded by the bytes that must hold them before any
importer allocates for them: a PLY's element counts by the file's size, a glTF's accessors
by their buffer views, the views by their buffers and the buffers by their files. (A PLY
claiming 2^31-1 vertices in 198 bytes crashed Blender's importer.)

An FBX file's textures are found by their node names (``RelativeFilename``, ``FileName``) in
its binary or ASCII node tree; its import, like every import, also runs in a child process
with a time and memory budget (``blender.trial_load``), which bounds whatever else it reads.
"""

from __future__ import annotations

import base64
import json
import mmap
import os
import pathlib
import re
import struct
import urllib.parse
from typing import Any

from . import limits
from .errors import VDNIFError
from .safe_io import check_input_file, shown

MTL_MAPS = re.compile(rb"^[ \t]*(map_\w+|bump|disp|decal|refl|norm)[ \t]+([^\r\n]+)",
                      re.M | re.I)
MTLLIB = re.compile(rb"^[ \t]*mtllib[ \t]+([^\r\n]+)", re.M)


def check_input(path: str | os.PathLike, label: str) -> int:
    """``safe_io.check_input_file`` plus the size bound; returns the file's size."""
    check_input_file(path, label)
    size = os.stat(path).st_size
    if size > limits.MAX_INPUT_FILE_BYTES:
        raise VDNIFError(f"{label} '{path}' has {size:,} bytes, more than the limit "
                         f"{limits.MAX_INPUT_FILE_BYTES:,} (vdnif_addon/limits.py)")
    return size


def check_mesh_file(path: str | os.PathLike) -> None:
    """Raises a one-line VDNIFError naming the file unless mesh file ``path``, every file it
    names that exists, and the counts of its header are sound (module docstring)."""
    path = pathlib.Path(path)
    size = check_input(path, "mesh file")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        _check_obj(path)
    elif suffix == ".ply":
        _check_ply(path, size)
    elif suffix in (".gltf", ".glb"):
        _check_gltf(path, size)
    elif suffix == ".fbx":
        _check_fbx(path)


def _side_file(candidates: list[pathlib.Path], label: str) -> int | None:
    """Checks each existing reading of a named file; its size, or None when none exists."""
    found = None
    for candidate in candidates:
        if os.path.lexists(candidate):
            found = check_input(candidate, label)
    return found


def _readings(text: str, folder: pathlib.Path) -> list[pathlib.Path]:
    """The files a name ``text`` in a file of ``folder`` may mean: the whole name, its last
    word (after an MTL line's options) and either's file name in ``folder`` (where
    importers look when a path from another machine is missing)."""
    names = {text.strip(), text.split()[-1] if text.split() else ""} - {""}
    paths = []
    for name in names:
        paths += [folder / name, folder / pathlib.PurePath(name.replace("\\", "/")).name]
    return list(dict.fromkeys(paths))


def _decoded(raw: bytes) -> str:
    return raw.decode("utf-8", "surrogateescape")


def _check_obj(path: pathlib.Path) -> None:
    folder = path.parent
    for raw in _matches(path, MTLLIB):
        text = _decoded(raw)
        libraries = _readings(text, folder) + [folder / word for word in text.split()]
        for library in dict.fromkeys(libraries):
            if not os.path.lexists(library):
                continue
            check_input(library, f"mesh file '{path}': material library")
            for _, name in MTL_MAPS.findall(library.read_bytes()):
                _side_file(_readings(_decoded(name), library.parent),
                           f"mesh file '{path}': material library '{library.name}': texture")


def _matches(path: pathlib.Path, pattern: re.Pattern) -> list[bytes]:
    """The first group of every match of ``pattern`` in the file (memory-mapped: an OBJ
    may be hundreds of MB)."""
    with open(path, "rb") as file:
        if os.fstat(file.fileno()).st_size == 0:
            return []
        with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return [match.group(1) for match in pattern.finditer(data)]


# A texture's file name in an FBX file: binary (a node named so, then its one string
# property: type "S", a 32-bit length, the bytes) or ASCII (``FileName: "..."``).
FBX_NAMES = re.compile(rb"(?:RelativeFilename|FileName)(?:S(.{4})|:[ \t]*\"([^\"\r\n]*)\")",
                       re.S)


def _check_fbx(path: pathlib.Path) -> None:
    with open(path, "rb") as file:
        if os.fstat(file.fileno()).st_size == 0:
            return
        with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
            names = []
            for match in FBX_NAMES.finditer(data):
                if match.group(1) is None:
                    names.append(match.group(2))
                else:
                    length = int.from_bytes(match.group(1), "little")
                    names.append(data[match.end():match.end() + min(length, 4096)])
    for name in dict.fromkeys(names):
        if name.strip():
            _side_file(_readings(_decoded(name), path.parent), f"mesh file '{path}': texture")


# --------------------------------------------------------------------------- PLY

PLY_TYPES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
             "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
             "float": 4, "float32": 4, "double": 8, "float64": 8}
PLY_HEADER_BYTES = 1 << 16
"""A PLY header longer than this is not a mesh's (a few hundred bytes are usual)."""


def _check_ply(path: pathlib.Path, size: int) -> None:
    """Each element's count times the fewest bytes one record can take (binary: its
    scalars and list counts; ASCII: a character and a separator per property) must fit in
    the bytes after the header."""
    with open(path, "rb") as file:
        head = file.read(PLY_HEADER_BYTES)
    end = re.search(rb"^end_header\r?\n", head, re.M)
    if not head.startswith(b"ply") or end is None:
        return                      # not a PLY header VDNIF can read: the importer says so
    elements: list[list[Any]] = []          # [name, count, fewest bytes]
    binary = True
    for line in _decoded(head[:end.start()]).splitlines():
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            binary = words[1] != "ascii"
        elif len(words) >= 3 and words[0] == "element":
            if not re.fullmatch(r"\d{1,20}", words[2]):
                raise VDNIFError(f"mesh file '{path}' is not a valid PLY file: element "
                                 f"'{shown(words[1])}' has the count {shown(words[2])}")
            elements.append([words[1], int(words[2]), 0])
        elif len(words) >= 3 and words[0] == "property" and elements:
            kind = words[2] if words[1] == "list" else words[1]
            elements[-1][2] += 2 if not binary else PLY_TYPES.get(kind, 1)
    room = size - end.end()
    needed = 0
    for name, count, fewest in elements:
        needed += count * max(fewest, 1)
        if needed > room:
            raise VDNIFError(f"mesh file '{path}' is damaged: its header claims {count:,} "
                             f"{shown(name)} elements, more than its {room:,} bytes of data "
                             "can hold")


# --------------------------------------------------------------------------- glTF

COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9,
                   "MAT4": 16}


def _gltf_document(path: pathlib.Path, size: int) -> tuple[Any, int | None]:
    """(the JSON document, the bytes of a GLB's binary chunk or None)."""
    data = path.read_bytes()
    binary = None
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise VDNIFError(f"mesh file '{path}' is not a valid GLB file: it is truncated")
        length, kind = struct.unpack_from("<I4s", data, 12)
        if kind != b"JSON" or 20 + length > len(data):
            raise VDNIFError(f"mesh file '{path}' is not a valid GLB file: its JSON chunk "
                             f"claims {length:,} bytes of {size:,}")
        text, rest = data[20:20 + length], data[20 + length:]
        if len(rest) >= 8 and rest[4:8] == b"BIN\x00":
            binary = min(struct.unpack_from("<I", rest)[0], len(rest) - 8)
    else:
        text = data
    try:
        return json.loads(text), binary
    except (ValueError, RecursionError):
        return None, binary             # not JSON: the importer says why


def _count(value: Any, default: int | None = None) -> int:
    if value is None and default is not None:
        return default
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{shown(value)} is not a count")
    return value


def _component(accessor: dict) -> int:
    kind = accessor.get("componentType")
    if kind not in COMPONENT_BYTES:
        raise ValueError(f"component type {shown(kind)} is not one of glTF's")
    return COMPONENT_BYTES[kind]


def _check_gltf(path: pathlib.Path, size: int) -> None:
    document, binary = _gltf_document(path, size)
    if not isinstance(document, dict):
        return
    try:
        _check_gltf_document(path, document, binary, size)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        raise VDNIFError(f"mesh file '{path}' is not a valid glTF file: {exc}") from None


def _check_gltf_document(path: pathlib.Path, document: dict, binary: int | None,
                         size: int) -> None:
    folder = path.parent
    held = []                                   # the bytes each buffer has behind it
    for index, buffer in enumerate(document.get("buffers") or []):
        uri = buffer.get("uri")
        if uri is None:
            available = binary or 0
        elif not isinstance(uri, str):
            raise ValueError(f"buffer {index} has the uri {shown(uri)}")
        elif uri.startswith("data:"):
            available = len(base64.b64decode(uri.partition(",")[2] + "==", validate=False))
        else:
            available = _side_file([folder / urllib.parse.unquote(uri)],
                                   f"mesh file '{path}': buffer") or 0
        declared = _count(buffer.get("byteLength"))
        if declared > available:
            raise VDNIFError(f"mesh file '{path}' is damaged: buffer {index} claims "
                             f"{declared:,} bytes, its data holds {available:,}")
        held.append(declared)
    for image in document.get("images") or []:
        uri = image.get("uri")
        if isinstance(uri, str) and not uri.startswith("data:"):
            _side_file([folder / urllib.parse.unquote(uri)], f"mesh file '{path}': image")
    views = []
    for index, view in enumerate(document.get("bufferViews") or []):
        end = _count(view.get("byteOffset"), 0) + _count(view.get("byteLength"))
        if end > held[_count(view.get("buffer"))]:
            raise VDNIFError(f"mesh file '{path}' is damaged: buffer view {index} ends at byte "
                             f"{end:,} of a buffer of {held[view['buffer']]:,}")
        views.append((_count(view.get("byteLength")), view.get("byteStride")))
    everything = size + sum(held)
    for index, accessor in enumerate(document.get("accessors") or []):
        element = _component(accessor) * TYPE_COMPONENTS.get(accessor.get("type"), 16)
        count = _count(accessor.get("count"))
        spans = [(accessor.get("bufferView"), accessor.get("byteOffset"), count, element)]
        sparse = accessor.get("sparse")
        if isinstance(sparse, dict):
            entries = _count(sparse.get("count"))
            spans += [(sparse["indices"].get("bufferView"), sparse["indices"].get("byteOffset"),
                       entries, _component(sparse["indices"])),
                      (sparse["values"].get("bufferView"), sparse["values"].get("byteOffset"),
                       entries, element)]
        for view, offset, items, item_bytes in spans:
            if view is None:                    # zeros: bounded by the whole file's bytes
                room, needed = everything, items * item_bytes
            else:
                length, stride = views[_count(view)]
                stride = _count(stride, item_bytes) or item_bytes
                room = length
                needed = _count(offset, 0) + (stride * (items - 1) + item_bytes if items else 0)
            if needed > room:
                raise VDNIFError(f"mesh file '{path}' is damaged: accessor {index} claims "
                                 f"{items:,} elements ({needed:,} bytes), its data holds "
                                 f"{room:,}")
