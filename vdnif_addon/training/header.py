"""The dataset header: what one shard ``<name>.npz`` holds, in ``<name>.json`` beside it, and
the folder's manifest, as frozen dataclasses.

``DatasetHeader.from_dict`` validates a header once, where it is read or written (types,
finite numbers, a complete grid, counts, pose range, heads and albedo table that agree);
readers then use attributes. ``to_dict`` gives the JSON shape on disk, ``FORMAT`` version
``VERSION`` (or 1, read as well); another version is refused with a line that says to
generate the dataset again.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np

from ..errors import VDNIFError
from ..geometry.capture import ARMATURE_COPY, CORNERS_FOLLOW
from ..geometry.voxels import GRID_KEYS, GridRecord
from ..limits import (
    MAX_OBJECT_SIZE,
    MAX_POSES,
    MAX_SHARD_SEGMENTS,
    MIN_OBJECT_SIZE,
)
from ..model.metadata import poses_problem
from ..safe_io import check_depth, finite_number, shown
from ..settings import BOUNDS, MAX_MATERIALS, Heads

FORMAT = "vdnif-dataset"
VERSION = 2
"""The format this VDNIF writes: version 2 stores the rows compactly (``packing``); version 1
(every array one row per segment) is read as well."""


def _fail(where: str, message: str) -> NoReturn:
    raise VDNIFError(f"{where}: {message}")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _int(where: str, name: str, value: object, low: int, high: int | None = None) -> int:
    if not _is_int(value) or value < low or (high is not None and value > high):
        span = f"{low}..{high}" if high is not None else f"at least {low}"
        _fail(where, f"{name} {shown(value)} is not an integer {span}")
    return value


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and finite_number(value)


def _number(where: str, name: str, value: object, low: float = -math.inf,
            high: float = math.inf) -> float:
    if not _is_number(value) or not low <= value <= high:
        span = "" if math.isinf(low) and math.isinf(high) else f" in {low:g}..{high:g}"
        _fail(where, f"{name} {shown(value)} is not a finite number{span}")
    return float(value)


def _object(where: str, name: str, value: object) -> dict[str, Any]:
    if not isinstance(value, dict):
        _fail(where, f"{name} is not a JSON object")
    return value


def _keys(where: str, name: str, data: Mapping[str, Any], required: tuple[str, ...],
          optional: tuple[str, ...] = ()) -> None:
    missing = [key for key in required if key not in data]
    unknown = sorted(set(data) - set(required) - set(optional))
    if missing:
        _fail(where, f"{name} lacks {', '.join(missing)}")
    if unknown:
        _fail(where, f"{name} has unknown entries {', '.join(map(shown, unknown))}")


HEAD_KEYS = ("occlusion", "distance", "normal", "albedo", "material", "material_count")


@dataclass(frozen=True)
class DatasetHeads:
    """The heads the scene needs (``RestMesh.heads``): occlusion, distance and normal always;
    albedo when it varies within a material; material when there are several; the mesh's
    material slot of each material index where the writer knew it."""

    albedo: bool
    material_count: int
    material_slots: tuple[int, ...] | None = None

    @property
    def material(self) -> bool:
        return self.material_count > 1

    def network_heads(self) -> Heads:
        """The network's heads for this dataset."""
        return Heads(albedo=self.albedo, material_count=self.material_count)

    def to_dict(self) -> dict[str, Any]:
        data = {"occlusion": True, "distance": True, "normal": True, "albedo": self.albedo,
                "material": self.material, "material_count": self.material_count}
        if self.material_slots is not None:
            data["material_slots"] = list(self.material_slots)
        return data

    @classmethod
    def from_dict(cls, data: object, where: str) -> DatasetHeads:
        data = _object(where, "heads", data)
        _keys(where, "heads", data, HEAD_KEYS, ("material_slots",))
        if any(data[key] is not True for key in ("occlusion", "distance", "normal")):
            _fail(where, "heads occlusion, distance and normal are not all true")
        count = _int(where, "heads material_count", data["material_count"], 1, MAX_MATERIALS)
        if not isinstance(data["albedo"], bool) or data["material"] is not (count > 1):
            _fail(where, f"heads albedo {shown(data['albedo'])} or material "
                         f"{shown(data['material'])} is not true or false as its {count} "
                         "materials say")
        slots = data.get("material_slots")
        if slots is not None and not (isinstance(slots, list) and len(slots) == count
                                      and all(_is_int(s) and s >= 0 for s in slots)):
            _fail(where, f"heads material_slots {shown(slots)} are not {count} slot indices")
        return cls(albedo=data["albedo"], material_count=count,
                   material_slots=None if slots is None else tuple(slots))


@dataclass(frozen=True)
class Counts:
    """Rays cast, segments walked, segments with a hit; rays the walk's bounds stopped where
    the writer counted them."""

    rays: int
    segments: int
    hits: int
    truncated_rays: int | None = None

    def to_dict(self) -> dict[str, int]:
        return {key: value for key, value in dataclasses.asdict(self).items()
                if value is not None}

    @classmethod
    def from_dict(cls, data: object, where: str) -> Counts:
        data = _object(where, "counts", data)
        _keys(where, "counts", data, ("rays", "segments", "hits"), ("truncated_rays",))
        values = {key: _int(where, f"counts {key}", value, 0) for key, value in data.items()}
        return cls(**values)


@dataclass(frozen=True)
class DatasetIdentity:
    """What a folder's shards share (its manifest ``vdnif-dataset.manifest``): the object,
    the grid's placement and the seed."""

    object: str
    seed: int
    grid: GridRecord

    def to_dict(self) -> dict[str, Any]:
        return {"object": self.object, "seed": self.seed,
                "grid": {key: self.grid.to_dict()[key] for key in GRID_KEYS}}

    def differs(self, other: DatasetIdentity) -> str | None:
        """The first of object, grid, seed on which ``other`` differs, or None."""
        for key, mine, theirs in (("object", self.object, other.object),
                                  ("grid", self.grid.placement(), other.grid.placement()),
                                  ("seed", self.seed, other.seed)):
            if mine != theirs:
                return key
        return None

    def describe(self) -> str:
        return f"'{self.object}' (seed {self.seed}, grid {list(self.grid.dims)})"

    @classmethod
    def from_dict(cls, data: object, where: str) -> DatasetIdentity:
        check_depth(data, where)
        if not isinstance(data, dict):
            _fail(where, "is not a JSON object")
        _keys(where, "manifest", data, ("object", "seed", "grid"))
        return cls(object=_name(where, data["object"]),
                   seed=_seed(where, data["seed"]),
                   grid=_grid(where, data["grid"]))


def _grid(where: str, data: object) -> GridRecord:
    """The grid entry ``data`` of the header or manifest that ``where`` names."""
    return GridRecord.from_dict(data, lambda problem: _fail(where, problem))


def _seed(where: str, value: object) -> int:
    """The seed of a header or manifest, in its settings' range."""
    return _int(where, "seed", value, *BOUNDS["seed"])


def _name(where: str, value: object) -> str:
    if not isinstance(value, str) or not value:
        _fail(where, "names no object")
    return value


HEADER_KEYS = ("format", "version", "object", "mode", "object_size", "grid", "voxel_size",
               "heads", "albedo_table", "poses", "pose_range", "seed", "rays_per_pose",
               "surface_fraction", "inverted_cells", "counts", "timings", "versions",
               "segments")


@dataclass(frozen=True)
class DatasetHeader:
    """One shard's header (``dataset.write_shard`` writes it, ``dataset.read_dataset`` reads
    it): the object and its deformation mode, its size (rest units), the grid, the heads and
    the albedo table (one RGB row per material), the poses of ``pose_range`` = (start, stop),
    the seed and ray mix they were walked with, per pose the inverted cells, the counts, the
    stage timings (seconds), the versions of the software, and the shard's row count."""

    version: int
    object: str
    mode: str
    object_size: float
    grid: GridRecord
    heads: DatasetHeads
    albedo_table: tuple[tuple[float, float, float], ...]
    poses: tuple[dict[str, Any], ...]
    pose_range: tuple[int, int]
    seed: int
    rays_per_pose: int
    surface_fraction: float
    grazing_fraction: float | None
    secondary_fraction: float | None
    inverted_cells: tuple[int, ...]
    counts: Counts
    timings: dict[str, float]
    versions: dict[str, str]
    segments: int
    corners_follow: str = ARMATURE_COPY     # absent from the shards of the armature copy
    view_rays: int = 0                      # per pose, after its training rays; absent: none

    @property
    def voxel_size(self) -> float:
        """h, rest units: the grid's voxel size."""
        return self.grid.voxel_size

    def identity(self) -> DatasetIdentity:
        return DatasetIdentity(object=self.object, seed=self.seed, grid=self.grid)

    def to_dict(self) -> dict[str, Any]:
        data = {"format": FORMAT, "version": self.version, "object": self.object,
                "mode": self.mode, "object_size": self.object_size,
                "grid": self.grid.to_dict(), "voxel_size": self.voxel_size,
                "heads": self.heads.to_dict(),
                "albedo_table": [list(row) for row in self.albedo_table],
                "poses": [dict(pose) for pose in self.poses],
                "pose_range": list(self.pose_range), "seed": self.seed,
                "rays_per_pose": self.rays_per_pose, "surface_fraction": self.surface_fraction}
        for key in ("grazing_fraction", "secondary_fraction"):    # absent in older shards
            if getattr(self, key) is not None:
                data[key] = getattr(self, key)
        data.update(inverted_cells=list(self.inverted_cells), counts=self.counts.to_dict(),
                    timings=dict(self.timings), versions=dict(self.versions),
                    segments=self.segments)
        if self.corners_follow != ARMATURE_COPY:
            data["corners_follow"] = self.corners_follow
        if self.view_rays:
            data["view_rays"] = self.view_rays
        return data

    @classmethod
    def from_dict(cls, data: object, where: str) -> DatasetHeader:
        """The header ``data`` (parsed JSON) validated; ``where`` names it in errors, e.g.
        "dataset header 'PATH'"."""
        check_depth(data, where)
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise VDNIFError(f"{where} is not a VDNIF dataset header")
        if not _is_int(data.get("version")) or not 1 <= data["version"] <= VERSION:
            raise VDNIFError(f"{where} has format version {shown(data.get('version'))}, this "
                             f"VDNIF reads versions 1 to {VERSION}: generate the dataset "
                             "again")
        grid = _grid(where, data.get("grid"))
        _keys(where, "header", data, HEADER_KEYS,
              ("grazing_fraction", "secondary_fraction", "corners_follow", "view_rays"))
        name = _name(where, data["object"])
        if data["voxel_size"] != grid.voxel_size:
            _fail(where, f"voxel size {shown(data['voxel_size'])} differs from the grid's "
                         f"{shown(grid.voxel_size)}")
        mode = data["mode"]
        if not isinstance(mode, str) or not mode:
            _fail(where, f"mode {shown(mode)} is not a name")
        heads = DatasetHeads.from_dict(data["heads"], where)
        poses, span = data["poses"], data["pose_range"]
        if (problem := poses_problem(poses, "poses are")) is not None:
            _fail(where, problem)
        if len(poses) > MAX_POSES:
            _fail(where, f"has {len(poses)} poses, more than the limit {MAX_POSES}")
        if not (isinstance(span, list) and len(span) == 2 and all(map(_is_int, span))
                and 0 <= span[0] < span[1] and span[1] - span[0] == len(poses)):
            _fail(where, f"pose range {shown(span)} is not two integers 0 <= start < stop that "
                         f"span its {len(poses)} poses")
        inverted = data["inverted_cells"]
        if not (isinstance(inverted, list) and len(inverted) == len(poses)
                and all(_is_int(n) and n >= 0 for n in inverted)):
            _fail(where, f"inverted_cells {shown(inverted)} are not one count per pose")
        timings, versions = (_object(where, "timings", data["timings"]),
                             _object(where, "versions", data["versions"]))
        for key, value in timings.items():
            _number(where, f"timing {key}", value, 0.0)
        if not all(isinstance(value, str) for value in versions.values()):
            _fail(where, "versions are not all strings")
        grazing, secondary = data.get("grazing_fraction"), data.get("secondary_fraction")
        follow = data.get("corners_follow", ARMATURE_COPY)
        if follow not in CORNERS_FOLLOW:
            _fail(where, f"corners follow {shown(follow)}, not one of "
                         f"{', '.join(CORNERS_FOLLOW)}")
        return cls(
            version=data["version"], object=name, mode=mode,
            object_size=_number(where, "object size", data["object_size"], MIN_OBJECT_SIZE,
                                MAX_OBJECT_SIZE),
            grid=grid, heads=heads,
            albedo_table=_albedo_table(where, data["albedo_table"], heads.material_count),
            poses=tuple(dict(pose) for pose in poses), pose_range=(span[0], span[1]),
            seed=_seed(where, data["seed"]),
            rays_per_pose=_int(where, "rays per pose", data["rays_per_pose"],
                               *BOUNDS["rays_per_pose"]),
            surface_fraction=_number(where, "surface fraction", data["surface_fraction"], 0, 1),
            grazing_fraction=(None if grazing is None
                              else _number(where, "grazing fraction", grazing, 0, 1)),
            secondary_fraction=(None if secondary is None
                                else _number(where, "secondary fraction", secondary, 0, 1)),
            inverted_cells=tuple(inverted), counts=Counts.from_dict(data["counts"], where),
            timings={key: float(value) for key, value in timings.items()},
            versions=dict(versions),
            segments=_int(where, "segments", data["segments"], 0, MAX_SHARD_SEGMENTS),
            corners_follow=follow,
            view_rays=_int(where, "view rays", data.get("view_rays", 0), 0,
                           MAX_SHARD_SEGMENTS))


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _albedo_table(where: str, table: object,
                  materials: int) -> tuple[tuple[float, float, float], ...]:
    """One finite RGB row per material, at least one."""
    if not (isinstance(table, list) and all(isinstance(row, list) and len(row) == 3
                                            and all(map(_is_number, row)) for row in table)):
        _fail(where, "the albedo table is not all finite numbers (rows of 3)")
    if len(table) < max(materials, 1):
        _fail(where, f"the albedo table has {len(table)} rows for {materials} materials")
    if not all(abs(value) <= _FLOAT32_MAX for row in table for value in row):
        _fail(where, "the albedo table has values beyond float32's range (training's type)")
    return tuple((float(r), float(g), float(b)) for r, g, b in table)

