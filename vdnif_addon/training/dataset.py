"""Training datasets: every walked segment with its targets, stored as shards.

A shard is ``<name>.npz`` (the arrays below, one row per segment, stored compactly:
``packing``) with ``<name>.json`` beside it (its ``header.DatasetHeader``: grid, heads, poses,
seed, counts, versions). Separate
processes write separate shards of disjoint pose ranges (``--pose-range``) into one folder;
training reads them all, lazily (``np.load`` of an npz reads an array only when it is used),
after checking every file is a regular one and every npz's sizes before reading an array.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import limits, threads
from ..errors import VDNIFError
from ..output_rule import DATASET_MANIFEST
from ..safe_io import ZIP_ERRORS, open_regular, unpacked_size
from .header import VERSION, DatasetHeader, DatasetIdentity
from .packing import PackedShard, pack, stored_names
from .shard_rows import ClosedNpz, check_lengths

if TYPE_CHECKING:
    from ..geometry.restmesh import RestMesh
    from ..geometry.voxels import GridRecord, VoxelGrid
    from ..geometry.walk_rules import Segments
    from ..tracing.groundtruth import SurfaceHits

    Shard = Mapping[str, np.ndarray]
    """One shard's arrays by ``ARRAYS`` name, each (S, ...) over its S segments (an npz
    file, read lazily)."""

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


ROW_BYTES = sum(np.dtype(kind).itemsize * math.prod(shape) for kind, shape in ARRAYS.values())
"""Bytes of one row (segment) in memory."""
SHARD_MEMORY_COPIES = 3
"""Copies of a shard's rows in memory at its peak: the poses' rows, their concatenation, and
the packed arrays being written (``write_shard``)."""


def check_shard_size(name: str, segments: float, memory: bool = True) -> None:
    """Refuses, before the rows are walked or held, a shard of about ``segments`` rows that
    is over ``limits.MAX_SHARD_SEGMENTS`` or (with ``memory``) that this machine's free
    memory cannot hold (``SHARD_MEMORY_COPIES`` x ``ROW_BYTES`` a row)."""
    from ..memory import check_memory

    advice = ("lower --rays-per-pose or --poses, or write the dataset in parts with "
              "--pose-range")
    if segments > limits.MAX_SHARD_SEGMENTS:
        raise VDNIFError(f"dataset shard '{name}' would hold about {round(segments):,} "
                         f"segments, more than the limit {limits.MAX_SHARD_SEGMENTS:,} "
                         f"(vdnif_addon/limits.py): {advice}")
    if memory:
        check_memory(f"dataset shard '{name}' ({round(segments):,} segments)",
                     segments * ROW_BYTES * SHARD_MEMORY_COPIES, advice)


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


def grid_header(grid: VoxelGrid, mesh: RestMesh | None = None) -> GridRecord:
    """The grid's header entry; with the RestMesh ``mesh`` it carries the mesh's fingerprint
    (``model_file.mesh_fingerprint``), which the model keeps with the grid, so that a mesh
    edited within the same bounds is refused by the model trained before the edit, and the
    fingerprint of its textures (``model_file.texture_fingerprint``) likewise."""
    fingerprint = textures = None
    if mesh is not None:
        from ..model.model_file import mesh_fingerprint, texture_fingerprint

        fingerprint, textures = mesh_fingerprint(mesh), texture_fingerprint(mesh)
    return grid.record(fingerprint, textures)


def shard_name(start: int, stop: int) -> str:
    """The name of the shard of poses ``start`` to ``stop`` (excluded): its files are
    ``<name>.npz`` and ``<name>.json``."""
    return f"shard-{start:06d}-{stop:06d}"


MANIFEST = DATASET_MANIFEST
"""The folder's manifest (JSON, ``DatasetIdentity``): the object, grid and seed its shards
were made of, so that a shard of another object, grid or seed is refused instead of replacing
one of the same pose range (shard names depend only on the pose range)."""


def check_folder(folder: str | os.PathLike, identity: DatasetIdentity) -> None:
    """Raises VDNIFError when dataset folder ``folder`` holds shards of another object, grid
    or seed than ``identity`` (its manifest, else the first shard header of an older
    folder)."""
    folder = pathlib.Path(folder)
    if os.path.lexists(folder) and not folder.is_dir():
        raise VDNIFError(f"dataset folder '{folder}' exists and is not a folder")
    theirs = _manifest(folder)
    if theirs is None:
        existing = sorted(folder.glob("*.json")) if folder.is_dir() else []
        if not existing:
            return
        theirs = _read_header(existing[0]).identity()
    key = theirs.differs(identity)
    if key is not None and not any(folder.glob("shard-*.json")):
        raise VDNIFError(f"dataset folder '{folder}' holds no shards, but its manifest "
                         f"'{MANIFEST}' is of object {theirs.describe()}, not of "
                         f"{identity.describe()}: its {key} differs; remove the manifest or "
                         "use another folder")
    if key is not None:
        raise VDNIFError(f"dataset folder '{folder}' holds shards of object "
                         f"{theirs.describe()}, not of {identity.describe()}: its {key} "
                         "differs; use another folder")


def write_shard(folder: str | os.PathLike, name: str, records: dict[str, np.ndarray],
                header: DatasetHeader) -> pathlib.Path:
    """Writes ``name.npz`` (the rows ``records``, ``ARRAYS``, packed: ``packing``) and
    ``name.json`` (``header``, as of this format version) into ``folder`` atomically
    (``safe_io``), after ``check_folder``; records the folder's manifest with the first
    shard. Returns the npz path."""

    from ..safe_io import atomic_path, json_text, write_text_atomic

    folder = pathlib.Path(folder)
    if header.segments != len(records["pose"]):
        raise VDNIFError(f"dataset shard '{name}': its header says {header.segments} "
                         f"segments, its arrays have {len(records['pose'])}")
    check_folder(folder, header.identity())
    header = replace(header, version=VERSION)
    text = json_text(header.to_dict(), f"dataset header of shard '{name}'", indent=1)
    if not (folder / MANIFEST).exists():
        write_text_atomic(folder / MANIFEST,
                          json_text(header.identity().to_dict(), "dataset manifest"),
                          "dataset manifest")
    target = folder / f"{name}.npz"
    with atomic_path(target, "dataset shard") as temporary:
        _write_npz(temporary, pack(records, header.heads))
    write_text_atomic(folder / f"{name}.json", text, "dataset header")
    return target


def _write_npz(path: str, arrays: dict[str, np.ndarray]) -> None:
    """``np.savez``'s archive (members stored, not compressed), written so that a failed
    write (a full disk) raises once: ``np.savez`` leaves its zip open on failure, and the
    zip's finalizer then writes its directory again and prints a second traceback after the
    error line."""
    with open(path, "wb") as file, zipfile.ZipFile(file, "w", zipfile.ZIP_STORED,
                                                   allowZip64=True) as archive:
        for name, array in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)


@dataclass(frozen=True)
class Dataset:
    """A dataset folder's shards read together (``dataset.read_dataset``): the header of the
    first (its object, grid, seed, heads and albedo table are every shard's), the shard
    names, every shard's poses in shard order, and their segments in all."""

    header: DatasetHeader
    shards: tuple[str, ...]
    poses: tuple[dict[str, Any], ...]
    segments: int


def read_dataset(folder: str | os.PathLike, defer_row_check: bool = False
                 ) -> tuple[Dataset, list[Shard]]:
    """(dataset, shards): the shards' headers read together and one lazy mapping of arrays
    per shard. The shards must agree with each other and with the folder's manifest on the
    object, grid and seed, and their pose ranges must not overlap (a pose counted twice).
    Their zip directories and array headers are checked here, and every array's values
    (``_check_shard``) here too, a read of the whole dataset (seconds per gigabyte), or with
    ``defer_row_check`` when a shard's rows are first read (``RowsCheckedOnRead``): a
    training then reads its rows once, and a caller that wants the header reads none."""
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise VDNIFError(f"dataset folder '{folder}' does not exist")
    paths = sorted(folder.glob("*.json"))
    if not paths:
        raise VDNIFError(f"dataset folder '{folder}' holds no shards (*.json + *.npz)")
    manifest = _manifest(folder)
    headers = []
    for path in paths:
        header = _read_header(path)
        first = manifest if manifest is not None or not headers else headers[0].identity()
        key = None if first is None else first.differs(header.identity())
        if key is not None:
            against = f"the manifest '{MANIFEST}'" if manifest else f"'{paths[0].name}'"
            raise VDNIFError(f"shard '{path}' was made from another {key} than {against}: "
                             f"{header.identity().describe()}, not {first.describe()}")
        if headers and (header.heads, header.albedo_table) != (headers[0].heads,
                                                               headers[0].albedo_table):
            raise VDNIFError(f"shard '{path}' has other heads or albedo table than "
                             f"'{paths[0].name}'")
        if headers and header.corners_follow != headers[0].corners_follow:
            raise VDNIFError(f"shard '{path}' was made with corners that follow the mesh "
                             f"as {header.corners_follow}, '{paths[0].name}' as "
                             f"{headers[0].corners_follow}: make every shard one way")
        if headers and ((header.rays_per_pose, header.view_rays)
                        != (headers[0].rays_per_pose, headers[0].view_rays)):
            # the calibration view's rows are told by their ray numbers (data.split_data)
            raise VDNIFError(f"shard '{path}' walked {header.rays_per_pose} rays per pose "
                             f"and a view of {header.view_rays}, '{paths[0].name}' "
                             f"{headers[0].rays_per_pose} and {headers[0].view_rays}: make "
                             "every shard with the same rays per pose")
        headers.append(header)
    _check_overlap(paths, headers)
    shards = []
    for path, header in zip(paths, headers):
        shard = _open_shard(path.with_suffix(".npz"), header)
        if defer_row_check:
            shard = RowsCheckedOnRead(shard, path.with_suffix(".npz"), header)
        else:
            _check_shard(path.with_suffix(".npz"), shard, header)
        shards.append(shard)
    merged = Dataset(header=headers[0], shards=tuple(path.stem for path in paths),
                     poses=tuple(pose for header in headers for pose in header.poses),
                     segments=sum(header.segments for header in headers))
    return merged, shards


def _check_overlap(paths: list[pathlib.Path], headers: list[DatasetHeader]) -> None:
    """Pose ranges of one folder's shards must not overlap: training would count a pose of
    both twice."""
    order = sorted(range(len(headers)), key=lambda i: headers[i].pose_range)
    for before, after in zip(order, order[1:]):
        (start, stop), (next_start, next_stop) = (headers[before].pose_range,
                                                  headers[after].pose_range)
        if next_start < stop:
            raise VDNIFError(
                f"dataset shards '{paths[before]}' (poses {start}:{stop}) and "
                f"'{paths[after].name}' (poses {next_start}:{next_stop}) overlap: a pose would "
                "be counted twice; remove one of them")


def _read_json(path: pathlib.Path, what: str) -> Any:
    """The JSON of regular file ``path`` of at most ``limits.MAX_HEADER_BYTES``; ``what``
    names it in errors."""
    try:
        with open_regular(path, f"{what} '{path}'") as file:
            text = file.read(limits.MAX_HEADER_BYTES + 1)
        if len(text) > limits.MAX_HEADER_BYTES:
            raise VDNIFError(f"{what} '{path}' is larger than the limit "
                             f"{limits.MAX_HEADER_BYTES:,} bytes (vdnif_addon/limits.py)")
        return json.loads(text)
    except RecursionError:
        raise VDNIFError(f"{what} '{path}' nests too deeply to be read") from None
    except (OSError, ValueError) as exc:
        raise VDNIFError(f"{what} '{path}' cannot be read: {exc}") from None


def _manifest(folder: pathlib.Path) -> DatasetIdentity | None:
    """The folder's manifest, or None for a folder without one."""
    path = folder / MANIFEST
    if not os.path.lexists(path):
        return None
    where = f"dataset manifest '{path}'"
    return DatasetIdentity.from_dict(_read_json(path, "dataset manifest"), where)


def _read_header(path: pathlib.Path) -> DatasetHeader:
    return DatasetHeader.from_dict(_read_json(path, "dataset header"),
                                   f"dataset header '{path}'")


def _open_shard(path: pathlib.Path, header: DatasetHeader) -> Shard:
    """The shard's rows (its npz as it is for a version 1 shard, else ``PackedShard``), its
    zip directory and array headers checked before any array is read: every member its
    version stores for its heads, their sizes within ``limits.MAX_SHARD_SEGMENTS`` rows, each
    array's header claiming the bytes its member holds."""
    file = open_regular(path, f"dataset shard '{path}'")
    size = os.fstat(file.fileno()).st_size
    try:
        unpacked = unpacked_size(file, f"dataset shard '{path}'")
    except VDNIFError:
        file.close()
        raise
    if unpacked is not None and unpacked > size:
        file.close()
        raise VDNIFError(f"dataset shard '{path}' is not a VDNIF shard: it would unpack to "
                         f"{unpacked:,} bytes from {size:,} (VDNIF stores its arrays "
                         "uncompressed)")
    try:
        shard = np.load(file)
    except ZIP_ERRORS as exc:
        file.close()
        raise VDNIFError(f"dataset shard '{path}' cannot be read: {exc}") from None
    if not isinstance(shard, np.lib.npyio.NpzFile):
        raise VDNIFError(f"dataset shard '{path}' is not an npz archive")
    names = tuple(ARRAYS) if header.version == 1 else stored_names(tuple(ARRAYS), header.heads)
    missing = set(names) - set(shard.files)
    if missing:
        raise VDNIFError(f"dataset shard '{path}' lacks {', '.join(sorted(missing))}")
    members = shard.zip.infolist()
    cap = limits.MAX_SHARD_SEGMENTS * _ROW_BYTES + _NPY_HEADER_BYTES * len(members)
    size = sum(info.file_size for info in members)
    if size > cap:
        raise VDNIFError(f"dataset shard '{path}' unpacks to {size:,} bytes, more than the "
                         f"limit {cap:,} ({limits.MAX_SHARD_SEGMENTS:,} segments, "
                         "vdnif_addon/limits.py)")
    for name in names:
        _check_member(path, shard, name)
    shard.close()
    file.close()
    archive = ClosedNpz(path, tuple(shard.files))
    return archive if header.version == 1 else PackedShard(archive, path, ARRAYS, header.heads,
                                                           header.albedo_table)


_ROW_BYTES = sum(np.dtype(dtype).itemsize * math.prod(trailing)
                 for dtype, trailing in ARRAYS.values())
_NPY_HEADER_BYTES = 1 << 14
"""The most bytes of an npy array header with its magic (numpy reads headers of at most
10,000 bytes)."""


def _check_member(path: pathlib.Path, shard: Shard, name: str) -> None:
    """The array header of member ``name``: its shape and dtype must claim exactly the bytes
    the member holds (an absurd row count is refused here, not by a failed allocation)."""
    info = shard.zip.getinfo(f"{name}.npy")
    try:
        with shard.zip.open(info) as member:
            version = np.lib.format.read_magic(member)
            read = {(1, 0): np.lib.format.read_array_header_1_0,
                    (2, 0): np.lib.format.read_array_header_2_0}.get(version)
            if read is None:
                raise ValueError(f"npy format version {version} is not 1.0 or 2.0")
            shape, _, dtype = read(member)
            start = member.tell()
    except ZIP_ERRORS as exc:
        raise VDNIFError(f"dataset shard '{path}' array '{name}' cannot be read: "
                         f"{_first_line(exc)}") from None
    if dtype.hasobject:
        return          # refused when read (no pickles), with numpy's own reason
    claimed = math.prod(shape) * dtype.itemsize
    if start + claimed != info.file_size:
        raise VDNIFError(f"dataset shard '{path}' array '{name}' claims shape {shape} "
                         f"({claimed:,} bytes), its member holds "
                         f"{info.file_size - start:,}")


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


# The rows' plausible ranges: normalized points lie in the grid's unit box (a margin for
# rounding at its walls), a hit's fraction along its segment in [0, 1].
_POINT_MARGIN = 0.01


class RowsCheckedOnRead(Mapping):
    """A shard whose rows are checked (``_check_shard``) when any of its arrays is first
    read: every array is read and checked then, before the first is given, and each is
    handed over once, so that the reader holds the only copy (a later read of it reads the
    file again)."""

    def __init__(self, shard: Shard, path: pathlib.Path, header: DatasetHeader) -> None:
        self.shard, self.path, self.header = shard, path, header
        self._unread: dict[str, np.ndarray] | None = None

    def __iter__(self) -> Iterator[str]:
        return iter(self.shard)

    def __len__(self) -> int:
        return len(self.shard)

    def __contains__(self, name: object) -> bool:
        return name in self.shard

    def __getitem__(self, name: str) -> np.ndarray:
        if self._unread is None:
            self._unread = _check_shard(self.path, self.shard, self.header, keep=True)
        if name in self._unread:
            return self._unread.pop(name)
        return self.shard[name]


READ_AT_ONCE = 2
"""Arrays of a shard that ``_check_shard`` reads and checks at once, each on a thread."""


def _read_array(path: pathlib.Path, shard: Shard, header: DatasetHeader, name: str
                ) -> tuple[np.ndarray, str | None]:
    """Array ``name`` of a shard, read and its kind and shape checked (a VDNIFError where
    either is wrong), and the first problem of its values (``_check_shard``'s checks of one
    array: finite, points in the grid, 0/1 hits, fractions, poses), or None."""
    dtype, trailing = ARRAYS[name]
    try:
        array = shard[name]
    except ZIP_ERRORS as exc:
        raise VDNIFError(f"dataset shard '{path}' array '{name}' cannot be read: "
                         f"{_first_line(exc)}") from None
    if array.dtype.kind != np.dtype(dtype).kind:
        raise VDNIFError(f"dataset shard '{path}' array '{name}' has dtype {array.dtype}, "
                         f"expected {np.dtype(dtype)}")
    if array.ndim < 1 or array.shape[1:] != trailing:
        raise VDNIFError(f"dataset shard '{path}' array '{name}' has shape {array.shape}, "
                         f"expected (N, {', '.join(map(str, trailing))})".replace(", )", ")"))
    if array.dtype.kind == "f" and not np.isfinite(array).all():
        return array, f"dataset shard '{path}' array '{name}' has non-finite values"
    if not len(array):
        return array, None
    if name in ("p0", "p1") and not (
            array.min() >= -_POINT_MARGIN and array.max() <= 1 + _POINT_MARGIN):
        return array, (f"dataset shard '{path}' array '{name}' has points outside the "
                       f"grid (normalized values {array.min():.3g}..{array.max():.3g})")
    if name == "hit" and array.max() > 1:
        return array, f"dataset shard '{path}' array 'hit' has values other than 0, 1"
    if name == "hit_frac" and not (array.min() >= 0 and array.max() <= 1):
        return array, (f"dataset shard '{path}' array 'hit_frac' has values outside "
                       "[0, 1]")
    if name == "pose" and not (header.pose_range[0] <= array.min()
                               and array.max() < header.pose_range[1]):
        return array, (f"dataset shard '{path}' array 'pose' has poses "
                       f"{array.min()}..{array.max()} outside its pose range "
                       f"{header.pose_range[0]}:{header.pose_range[1]}")
    return array, None


def _check_shard(path: pathlib.Path, shard: Shard, header: DatasetHeader, keep: bool = False
                 ) -> dict[str, np.ndarray]:
    """Every array of a shard read once and checked against ``ARRAYS`` and its header: kind
    of dtype, shape, length (the header's segment count), finite values, normalized points
    within the grid, 0/1 hits, fractions in [0, 1], poses of the header. A bad CRC or a
    truncated member is reported here, not in the middle of training. Returns the arrays
    read with ``keep`` (those a packed shard makes from its header's table are not read),
    else none: each array is let go once checked.

    Two arrays are read and checked at a time, each on a thread of its own (reading an
    array's bytes, unpacking it and numpy's checks release the GIL, so the two overlap); the
    first problem in ``ARRAYS``' order is reported, as a read of one at a time would."""
    names = [name for name in ARRAYS
             if not (isinstance(shard, PackedShard) and name not in shard.stored)]
    length = None
    kept = {}
    read = {}
    for name, (array, problem) in zip(names, threads.in_order(
            names, lambda name: _read_array(path, shard, header, name), READ_AT_ONCE,
            "vdnif-read")):
        if keep:
            read[name] = array
        if name in ("p0", "p1", "rest_len", "seg_len", "t0", "hit", "normal"):
            kept[name] = array
        if length is None:
            length = len(array)
        if len(array) != length:
            raise VDNIFError(f"dataset shard '{path}' array '{name}' has {len(array)} rows, "
                             f"'p0' has {length}")
        if problem is not None:
            raise VDNIFError(problem)
    if header.segments != length:
        raise VDNIFError(f"dataset shard '{path}' has {length} rows, its header says "
                         f"{header.segments}")
    check_lengths(path, kept, header.grid.extent)
    return read
