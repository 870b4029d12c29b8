"""Training datasets: every walked segment with its targets, stored as shards.

A shard is ``<name>.npz`` (the arrays below, one row per segment) with ``<name>.json`` beside
it (grid, heads, poses, seeds, counts, versions). Separate processes write separate shards
(``--pose-range``) into one folder; training reads them all, lazily (``np.load`` of an npz
reads an array only when it is used).
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import zipfile
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import VDNIFError

if TYPE_CHECKING:
    from ..geometry.restmesh import RestMesh
    from ..geometry.voxels import VoxelGrid
    from ..geometry.walk_rules import Segments
    from ..tracing.groundtruth import SurfaceHits

    Shard = Mapping[str, np.ndarray]
    """One shard's arrays by ``ARRAYS`` name, each (S, ...) over its S segments (an npz
    file, read lazily)."""

FORMAT = "vdnif-dataset"
VERSION = 1
ARRAYS = {                     # name: (dtype, trailing shape)
    "p0": (np.float32, (3,)),        # normalized rest entry point, grid.normalize
    "p1": (np.float32, (3,)),        # normalized rest exit point
    "seg_len": (np.float32, ()),     # deformed segment length l
    "rest_len": (np.float32, ()),    # rest segment length |p1 - p0| (rest units)
    "t0": (np.float32, ()),          # deformed distance from the ray origin to the entry
    "hit": (np.uint8, ()),
    "hit_frac": (np.float32, ()),    # s: hit position along the segment, 0..1
    "normal": (np.float32, (3,)),    # rest-space unit shading normal
    "albedo": (np.float32, (3,)),
    "material": (np.int16, ()),
    "pose": (np.int32, ()),
    "ray": (np.int32, ()),
}
GRID_KEYS = ("origin", "voxel_size", "dims", "resolution", "extent")


def segment_records(grid: VoxelGrid, segments: Segments, targets: SurfaceHits,
                    pose_index: int) -> dict[str, np.ndarray]:
    """The shard rows for one pose's Segments and their SurfaceHits targets: per ``ARRAYS``
    name an (S, ...) array of its dtype over the S segments."""
    rest_len = np.linalg.norm(segments.p1 - segments.p0, axis=1)
    fraction = np.where(targets.hit & (rest_len > 0),
                        targets.distance / np.where(rest_len > 0, rest_len, 1.0), 0.0)
    records = {
        "p0": grid.normalize(segments.p0), "p1": grid.normalize(segments.p1),
        "seg_len": segments.length, "rest_len": rest_len, "t0": segments.t0,
        "hit": targets.hit, "hit_frac": np.clip(fraction, 0.0, 1.0),
        "normal": targets.normal, "albedo": targets.albedo, "material": targets.material,
        "pose": np.full(len(segments), pose_index), "ray": segments.ray,
    }
    return {name: np.asarray(value).astype(ARRAYS[name][0]) for name, value in records.items()}


def grid_header(grid: VoxelGrid, mesh: RestMesh | None = None) -> dict[str, Any]:
    """The grid's header entry; with the RestMesh ``mesh`` it carries the mesh's fingerprint
    (``model_file.mesh_fingerprint``), which the model keeps with the grid, so that a mesh
    edited within the same bounds is refused by the model trained before the edit."""
    header = {"origin": grid.origin.tolist(), "voxel_size": grid.voxel_size,
              "dims": grid.dims.tolist(), "resolution": grid.resolution, "extent": grid.extent,
              "occupied_voxels": int(len(grid.cells))}
    if mesh is not None:
        from ..model.model_file import mesh_fingerprint

        header["mesh_fingerprint"] = mesh_fingerprint(mesh)
    return header


MANIFEST = "vdnif-dataset.manifest"
"""The folder's manifest (JSON): the object, grid and seed its shards were made of, so that a
shard of another object, grid or seed is refused instead of replacing one of the same pose
range (shard names depend only on the pose range)."""
MANIFEST_KEYS = ("object", "grid", "seed")


def _identity(header: dict[str, Any]) -> dict[str, Any]:
    grid = header.get("grid") if isinstance(header.get("grid"), dict) else {}
    return {"object": header.get("object"), "seed": header.get("seed"),
            "grid": {key: grid.get(key) for key in GRID_KEYS}}


def check_folder(folder: str | os.PathLike, header: dict[str, Any]) -> None:
    """Raises VDNIFError when dataset folder ``folder`` holds shards of another object, grid
    or seed than ``header`` (its manifest, else the first shard header of an older folder)."""
    folder = pathlib.Path(folder)
    if os.path.lexists(folder) and not folder.is_dir():
        raise VDNIFError(f"dataset folder '{folder}' exists and is not a folder")
    mine = _identity(header)
    manifest = folder / MANIFEST
    if manifest.exists():
        try:
            theirs = json.loads(manifest.read_text())
        except (OSError, ValueError) as exc:
            raise VDNIFError(f"dataset manifest '{manifest}' cannot be read: {exc}") from None
    else:
        existing = sorted(folder.glob("*.json")) if folder.is_dir() else []
        if not existing:
            return
        theirs = _identity(_read_header(existing[0]))
    if not isinstance(theirs, dict):
        raise VDNIFError(f"dataset manifest '{manifest}' is not a JSON object")
    for key in MANIFEST_KEYS:
        if json.dumps(theirs.get(key), sort_keys=True) != json.dumps(mine[key],
                                                                     sort_keys=True):
            raise VDNIFError(
                f"dataset folder '{folder}' holds shards of object '{theirs.get('object')}' "
                f"(seed {theirs.get('seed')}, grid {(theirs.get('grid') or {}).get('dims')}), "
                f"not of '{mine['object']}' (seed {mine['seed']}, grid "
                f"{mine['grid'].get('dims')}): its {key} differs; use another folder")


def write_shard(folder: str | os.PathLike, name: str, records: dict[str, np.ndarray],
                header: dict[str, Any]) -> pathlib.Path:
    """Writes ``name.npz`` and ``name.json`` into ``folder`` atomically (``safe_io``), after
    ``check_folder``; records the folder's manifest with the first shard. Returns the npz
    path."""
    from ..safe_io import atomic_path, json_text, write_text_atomic

    folder = pathlib.Path(folder)
    check_folder(folder, header)
    header = {"format": FORMAT, "version": VERSION, **header,
              "segments": int(len(records["pose"]))}
    text = json_text(header, f"dataset header of shard '{name}'", indent=1)
    if not (folder / MANIFEST).exists():
        write_text_atomic(folder / MANIFEST, json_text(_identity(header), "dataset manifest"),
                          "dataset manifest")
    target = folder / f"{name}.npz"
    with atomic_path(target, "dataset shard") as temporary:
        np.savez(temporary, **records)
    write_text_atomic(folder / f"{name}.json", text, "dataset header")
    return target


def read_dataset(folder: str | os.PathLike) -> tuple[dict[str, Any], list[Shard]]:
    """(header, shards): the merged header and one lazy mapping of arrays per shard."""
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise VDNIFError(f"dataset folder '{folder}' does not exist")
    headers = sorted(folder.glob("*.json"))
    if not headers:
        raise VDNIFError(f"dataset folder '{folder}' holds no shards (*.json + *.npz)")
    merged, shards = None, []
    for path in headers:
        header = _read_header(path)
        shards.append(_open_shard(path.with_suffix(".npz")))
        _check_header(path, header)
        _check_shard(path.with_suffix(".npz"), shards[-1], header)
        if merged is None:
            merged = dict(header, shards=[], poses=[])
        elif any(header["grid"][k] != merged["grid"][k] for k in GRID_KEYS) or (
                header["object"] != merged["object"]):
            raise VDNIFError(f"shard '{path.name}' was made from another object or grid "
                             f"than '{headers[0].name}'")
        merged["shards"].append(path.stem)
        merged["poses"] += header["poses"]
    merged["segments"] = sum(len(s["pose"]) for s in shards)
    return merged, shards


def _read_header(path: pathlib.Path) -> dict[str, Any]:
    try:
        header = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise VDNIFError(f"dataset header '{path}' cannot be read: {exc}") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise VDNIFError(f"'{path}' is not a VDNIF dataset header")
    if header.get("version") != VERSION:
        raise VDNIFError(f"dataset '{path}' has format version {header.get('version')}, "
                         f"this VDNIF reads version {VERSION}")
    return header


def _open_shard(path: pathlib.Path) -> Shard:
    try:
        shard = np.load(path)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise VDNIFError(f"dataset shard '{path}' cannot be read: {exc}") from None
    missing = set(ARRAYS) - set(shard.files)
    if missing:
        raise VDNIFError(f"dataset shard '{path}' lacks {', '.join(sorted(missing))}")
    return shard


def _finite_number(value: object, positive: bool = False) -> bool:
    return (not isinstance(value, bool) and isinstance(value, (int, float))
            and math.isfinite(value) and (value > 0 or not positive))


def _check_header(path: pathlib.Path, header: dict[str, Any]) -> None:
    """A shard header that agrees with itself: a complete grid of finite numbers, a voxel size
    equal to the grid's, the poses of its pose range, a finite albedo table."""
    grid = header.get("grid")
    if not isinstance(grid, dict) or any(key not in grid for key in GRID_KEYS):
        raise VDNIFError(f"dataset header '{path}' has no complete grid "
                         f"({', '.join(GRID_KEYS)})")
    if not isinstance(header.get("object"), str) or not header["object"]:
        raise VDNIFError(f"dataset header '{path}' names no object")
    origin, dims = grid["origin"], grid["dims"]
    if not (isinstance(origin, list) and len(origin) == 3 and all(map(_finite_number, origin))):
        raise VDNIFError(f"dataset header '{path}': grid origin {origin!r} is not 3 numbers")
    if not (isinstance(dims, list) and len(dims) == 3
            and all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in dims)):
        raise VDNIFError(f"dataset header '{path}': grid dims {dims!r} are not 3 counts")
    h, resolution = grid["voxel_size"], grid["resolution"]
    if not _finite_number(h, positive=True) or not _finite_number(grid["extent"], True):
        raise VDNIFError(f"dataset header '{path}': grid voxel size or extent is not a "
                         "positive number")
    if abs(grid["extent"] - h * max(dims)) > 1e-6 * grid["extent"]:
        raise VDNIFError(f"dataset header '{path}': grid extent {grid['extent']!r} is not its "
                         f"voxel size {h!r} times its longest dims {max(dims)}")
    from ..geometry.voxels import MAX_RESOLUTION, MIN_RESOLUTION

    if (not isinstance(resolution, int) or isinstance(resolution, bool)
            or not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION):
        raise VDNIFError(f"dataset header '{path}': grid resolution {resolution!r} is not an "
                         f"integer in {MIN_RESOLUTION}..{MAX_RESOLUTION}")
    if "voxel_size" in header and header["voxel_size"] != h:
        raise VDNIFError(f"dataset header '{path}': voxel size {header['voxel_size']!r} differs "
                         f"from the grid's {h!r}")
    if not isinstance(header.get("poses"), list):
        raise VDNIFError(f"dataset header '{path}' has no list of poses")
    span = header.get("pose_range")
    if span is not None and (not isinstance(span, list) or len(span) != 2
                             or span[1] - span[0] != len(header["poses"])):
        raise VDNIFError(f"dataset header '{path}': pose range {span!r} does not match its "
                         f"{len(header['poses'])} poses")
    table = header.get("albedo_table")
    if table is not None:
        try:
            finite = np.isfinite(np.asarray(table, np.float64)).all()
        except (TypeError, ValueError):
            finite = False
        if not finite:
            raise VDNIFError(f"dataset header '{path}': the albedo table is not all finite "
                             "numbers")


# The rows' plausible ranges: normalized points lie in the grid's unit box (a margin for
# rounding at its walls), a hit's fraction along its segment in [0, 1].
_POINT_MARGIN = 0.01


def _check_shard(path: pathlib.Path, shard: Shard, header: dict[str, Any]) -> None:
    """Every array of a shard read once and checked against ``ARRAYS`` and its header: kind
    of dtype, shape, length (the header's segment count), finite values, normalized points
    within the grid, 0/1 hits, fractions in [0, 1], poses of the header. A bad CRC or a
    truncated member is reported here, not in the middle of training."""
    length = None
    for name, (dtype, trailing) in ARRAYS.items():
        try:
            array = shard[name]
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise VDNIFError(f"dataset shard '{path}' array '{name}' cannot be read: "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                             ) from None
        if array.dtype.kind != np.dtype(dtype).kind:
            raise VDNIFError(f"dataset shard '{path}' array '{name}' has dtype {array.dtype}, "
                             f"expected {np.dtype(dtype)}")
        if array.ndim < 1 or array.shape[1:] != trailing:
            raise VDNIFError(f"dataset shard '{path}' array '{name}' has shape {array.shape}, "
                             f"expected (N, {', '.join(map(str, trailing))})".replace(", )", ")"))
        if length is None:
            length = len(array)
        if len(array) != length:
            raise VDNIFError(f"dataset shard '{path}' array '{name}' has {len(array)} rows, "
                             f"'p0' has {length}")
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            raise VDNIFError(f"dataset shard '{path}' array '{name}' has non-finite values")
        if name in ("p0", "p1") and length and not (
                array.min() >= -_POINT_MARGIN and array.max() <= 1 + _POINT_MARGIN):
            raise VDNIFError(f"dataset shard '{path}' array '{name}' has points outside the "
                             f"grid (normalized values {array.min():.3g}..{array.max():.3g})")
        if name == "hit" and length and array.max() > 1:
            raise VDNIFError(f"dataset shard '{path}' array 'hit' has values other than 0, 1")
        if name == "hit_frac" and length and not (array.min() >= 0 and array.max() <= 1):
            raise VDNIFError(f"dataset shard '{path}' array 'hit_frac' has values outside "
                             "[0, 1]")
    segments = header.get("segments")
    if segments is not None and segments != length:
        raise VDNIFError(f"dataset shard '{path}' has {length} rows, its header says "
                         f"{segments}")
