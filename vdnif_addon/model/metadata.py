"""What a saved model knows of itself: the scene it was trained on (object, grid, material
slots, albedo table, training poses), its network config, its calibrated thresholds and how
training went. ``ModelMetadata`` is frozen and checked once, in ``from_dict`` when a file is
read and in the constructor when training makes one; readers use its attributes.

The model file stores ``to_dict()``, plain data (numbers, strings, lists, dicts), as its
metadata payload (``model_file``).
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from ..errors import VDNIFError
from ..geometry.capture import ARMATURE_COPY, CORNERS_FOLLOW
from ..geometry.voxels import GridRecord
from ..safe_io import check_depth, finite_number, first_non_plain, shown
from ..settings import OCCLUSION_THRESHOLD, NetworkConfig

if TYPE_CHECKING:
    from jaxtyping import Float

FORMAT_VERSION = 3
"""The model file's format: 3 holds ``ModelMetadata.to_dict()``. Files of an older format
are refused (retrain them)."""


def poses_problem(poses: Any, subject: str) -> str | None:
    """Why ``poses`` (a dataset header's or a model's training poses, ``subject`` naming
    them with their verb: "poses are") is not a list of pose descriptions
    (``poses.make_poses``: plain-data mappings with text keys, each with a finite frame, or
    the rest pose ``{"rest": True}`` that a static variant trains on), or None. Call after
    ``check_depth``."""
    if not isinstance(poses, (list, tuple)) or not all(
            isinstance(pose, Mapping) for pose in poses):
        return f"{subject} not a list of pose descriptions (JSON objects)"
    if (bad := first_non_plain(poses)) is not None:
        return f"pose figure 'poses{bad}' is not a finite number or plain data"
    for index, pose in enumerate(poses):
        if pose.get("rest") is not True and not finite_number(pose.get("frame")):
            return f"pose {index} has no finite frame number"
    return None


def albedo_rows(table: Any) -> tuple[tuple[float, float, float], ...]:
    """An albedo table (rows of RGB) as a model keeps it: in float32, the render kernels'
    type, so that a model made in training holds what its file gives back."""
    rows = np.asarray(table, np.float64).reshape(-1, 3).astype(np.float32)
    return tuple(tuple(row) for row in rows.tolist())


_PROBLEM_CHARS = 300
"""The longest description of a problem in a message: one line a user reads."""


class _Reader:
    """Typed reads of one plain-data mapping of the model file ``path``; every failure is a
    one-line VDNIFError naming the file and the entry (``where``)."""

    def __init__(self, path: str, data: Any, where: str = "") -> None:
        self.path, self.where = path, where
        if not isinstance(data, Mapping):
            self.fail(f"{where or 'its metadata'} is not a mapping")
        self.data = data

    def fail(self, problem: str) -> NoReturn:
        if len(problem) > _PROBLEM_CHARS:       # a huge value quoted by a settings check
            problem = problem[:_PROBLEM_CHARS] + "..."
        raise VDNIFError(f"model file {self.path} is damaged: {problem}")

    def name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def get(self, key: str) -> Any:
        if key not in self.data:
            self.fail(f"its metadata has no {self.name(key)}")
        return self.data[key]

    def child(self, key: str, default: Any = None) -> _Reader:
        """The mapping at ``key`` (``default`` when absent and given)."""
        value = self.data.get(key, default) if default is not None else self.get(key)
        return _Reader(self.path, value, self.name(key))

    def text(self, key: str) -> str:
        value = self.get(key)
        if not isinstance(value, str):
            self.fail(f"its metadata {self.name(key)} {shown(value)} is not text")
        return value

    def integer(self, key: str, minimum: int = 0) -> int:
        value = self.get(key)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or (
                value < minimum):
            self.fail(f"its metadata {self.name(key)} {shown(value)} is not an integer of at "
                      f"least {minimum}")
        return int(value)

    def number(self, key: str, positive: bool = False) -> float:
        value = self.get(key)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            self.fail(f"its metadata {self.name(key)} {shown(value)} is not a number")
        if not finite_number(value):
            self.fail(f"its metadata {self.name(key)} has non-finite values")
        if positive and not value > 0:
            self.fail(f"its metadata {self.name(key)} {shown(value)} must be positive")
        return float(value)

    def array(self, key: str, dtype: type, shape: tuple[int | None, ...]) -> np.ndarray:
        """Numbers of ``shape`` (None: any length), finite."""
        value = self.get(key)
        try:
            with np.errstate(invalid="ignore", over="ignore"):     # refused just below
                array = np.asarray(value, dtype)
        except (TypeError, ValueError, OverflowError):
            self.fail(f"its metadata {self.name(key)} is not numbers")
        if array.ndim != len(shape) or any(
                n is not None and size != n for size, n in zip(array.shape, shape)):
            wanted = "x".join("n" if n is None else str(n) for n in shape)
            self.fail(f"its metadata {self.name(key)} has shape {array.shape}, not {wanted}")
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            self.fail(f"its metadata {self.name(key)} has non-finite values")
        if array.dtype.kind in "iu" and not np.array_equal(array, np.asarray(value)):
            self.fail(f"its metadata {self.name(key)} is not integers")
        return array

    def optional_numbers(self, key: str) -> dict[str, float | None] | None:
        """A mapping of names to finite numbers (or None), or None."""
        value = self.get(key)
        if value is None:
            return None
        reader = self.child(key)
        if not all(isinstance(name, str) for name in reader.data):
            self.fail(f"its metadata {self.name(key)} has names that are not text")
        return {name: None if item is None else reader.number(name)
                for name, item in reader.data.items()}


@dataclass(frozen=True)
class Thresholds:
    """The occlusion probability above which a segment is a hit, and the lower one above
    which a ray's first segment places its hit (DESIGN section 9). Training calibrates both
    on held-out poses; until then both are ``OCCLUSION_THRESHOLD``."""

    occlusion: float = OCCLUSION_THRESHOLD
    candidate: float = OCCLUSION_THRESHOLD

    def __post_init__(self) -> None:
        for name in ("occlusion", "candidate"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (
                    0 < value <= 1):
                raise VDNIFError(f"{name} threshold {shown(value)} must lie in (0, 1]")
        if self.candidate > self.occlusion:
            raise VDNIFError(f"candidate threshold {self.candidate} must be at most the "
                             f"occlusion threshold {self.occlusion}")

    def to_dict(self) -> dict[str, float]:
        """Plain data for the model file."""
        return {"occlusion": float(self.occlusion), "candidate": float(self.candidate)}

    @classmethod
    def read(cls, reader: _Reader) -> Thresholds:
        """From the model file's entry (``reader``)."""
        return cls(reader.number("occlusion"), reader.number("candidate"))


@dataclass(frozen=True)
class TrainingSummary:
    """How training went (``train.TrainResult.summary``): status ("completed" or
    "cancelled"), optimizer steps, wall seconds and samples per second, the metrics on the
    held-out poses (None without any), the loss weighting's final log-variances, the
    held-out pose indices, the processes and the TrainConfig as plain data."""

    status: str
    steps: int
    seconds: float
    samples_per_s: float
    validation: Mapping[str, float | None] | None
    log_variances: Mapping[str, float]
    val_poses: tuple[int, ...]
    world_size: int
    config: Mapping[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-ready)."""
        return {"status": self.status, "steps": self.steps, "seconds": self.seconds,
                "samples_per_s": self.samples_per_s,
                "validation": None if self.validation is None else dict(self.validation),
                "log_variances": dict(self.log_variances), "val_poses": list(self.val_poses),
                "world_size": self.world_size, "config": dict(self.config)}

    @classmethod
    def read(cls, reader: _Reader) -> TrainingSummary:
        """From the model file's entry (``reader``)."""
        config = reader.child("config")
        return cls(status=reader.text("status"), steps=reader.integer("steps"),
                   seconds=reader.number("seconds"),
                   samples_per_s=reader.number("samples_per_s"),
                   validation=reader.optional_numbers("validation"),
                   log_variances=reader.optional_numbers("log_variances") or {},
                   val_poses=tuple(reader.array("val_poses", np.int64, (None,)).tolist()),
                   world_size=reader.integer("world_size", 1), config=dict(config.data))


@dataclass(frozen=True)
class DatasetSource:
    """The dataset the model was trained on: folder, shard names, pose and segment counts."""

    folder: str
    shards: tuple[str, ...]
    poses: int
    segments: int

    def to_dict(self) -> dict[str, Any]:
        """Plain data."""
        return {"folder": self.folder, "shards": list(self.shards), "poses": self.poses,
                "segments": self.segments}

    @classmethod
    def read(cls, reader: _Reader) -> DatasetSource:
        """From the model file's entry (``reader``)."""
        shards = reader.get("shards")
        if not isinstance(shards, (list, tuple)) or not all(isinstance(s, str) for s in shards):
            reader.fail("its metadata dataset.shards is not a list of names")
        return cls(folder=reader.text("folder"), shards=tuple(shards),
                   poses=reader.integer("poses"), segments=reader.integer("segments"))


@dataclass(frozen=True)
class ModelMetadata:
    """Everything a model file holds besides its weights (module docstring).

    ``material_slots``: the object's used material slots, the network's materials in order;
    ``albedo_table``: (rows, 3) constant albedo per material, read by the render kernels by
    material (at least ``network_config.heads.material_count`` rows); ``train_poses``: the
    pose descriptions trained on (``poses.make_poses``), which evaluation avoids;
    ``corners_follow``: how its voxel corners followed the mesh (``geometry.capture``; a
    file written before it was recorded followed the armature copy).
    """

    object: str
    object_size: float
    variant: str
    network_config: NetworkConfig
    grid: GridRecord
    material_slots: tuple[int, ...]
    albedo_table: tuple[tuple[float, float, float], ...]
    thresholds: Thresholds
    train_poses: tuple[Mapping[str, Any], ...]
    training: TrainingSummary
    dataset: DatasetSource
    vdnif_version: str
    version: int = FORMAT_VERSION
    corners_follow: str = ARMATURE_COPY

    def __post_init__(self) -> None:
        materials = self.network_config.heads.material_count
        if len(self.albedo_table) < materials:
            raise VDNIFError(f"its albedo table has {len(self.albedo_table)} rows for "
                             f"{materials} materials")
        if len(self.material_slots) != materials or min(self.material_slots) < 0:
            raise VDNIFError(f"its material slots {list(self.material_slots)} are not "
                             f"{materials} slot indices")
        if self.corners_follow not in CORNERS_FOLLOW:
            raise VDNIFError(f"its corners follow {shown(self.corners_follow)}, not one of "
                             f"{', '.join(CORNERS_FOLLOW)}")
        if (bad := first_non_plain(self.to_dict())) is not None:   # e.g. a NaN metric
            raise VDNIFError(f"its metadata entry '{bad}' is not a finite number or plain "
                             "data")

    def albedo_colors(self) -> Float[np.ndarray, "rows 3"]:
        """The albedo table as the render kernels read it, (rows, 3) float32."""
        return np.array(self.albedo_table, np.float32).reshape(-1, 3)

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the model file (numbers, strings, lists, dicts)."""
        return {"version": self.version, "object": self.object,
                "object_size": self.object_size, "variant": self.variant,
                "network_config": self.network_config.to_dict(),
                "grid": self.grid.to_dict(with_none=True),
                "material_slots": list(self.material_slots),
                "albedo_table": [list(row) for row in self.albedo_table],
                "thresholds": self.thresholds.to_dict(),
                "train_poses": [dict(pose) for pose in self.train_poses],
                "training": self.training.to_dict(), "dataset": self.dataset.to_dict(),
                "vdnif_version": self.vdnif_version,
                # written where it is not the copies', so a file of an armature or lattice
                # rig is as it was before the surface binding
                **({} if self.corners_follow == ARMATURE_COPY
                   else {"corners_follow": self.corners_follow})}

    @classmethod
    def from_dict(cls, data: Any, path: str) -> ModelMetadata:
        """Inverse of ``to_dict`` for the model file ``path``: every entry checked (types,
        finite numbers, a complete grid, the albedo table and the material slots against
        the network's materials, thresholds in (0, 1]); a failure is a one-line VDNIFError
        naming the file. Training (``training.fit``) makes its metadata with the constructor,
        from values it holds, never through plain data."""
        check_depth(data, f"model file {path} is damaged: its metadata")
        reader = _Reader(path, data)
        version = reader.integer("version")
        if version != FORMAT_VERSION:
            raise VDNIFError(outdated(path, version))
        if (bad := first_non_plain(reader.get("network_config"))) is not None:
            reader.fail(f"its metadata entry 'network_config.{bad}' is not a finite number or "
                        "plain data")
        try:
            config = NetworkConfig.from_dict(reader.get("network_config"))
        except (VDNIFError, TypeError) as exc:
            reader.fail(f"its network config is invalid: {exc}")
        poses = reader.get("train_poses")
        if (problem := poses_problem(poses, "its metadata train_poses is")) is not None:
            reader.fail(problem)
        with np.errstate(over="ignore"):                            # refused just below
            albedo = reader.array("albedo_table", np.float64, (None, 3)).astype(np.float32)
        if not np.isfinite(albedo).all():
            reader.fail("its metadata albedo_table has values beyond float32's range")
        try:
            metadata = cls(object=reader.text("object"),
                       object_size=reader.number("object_size", positive=True),
                       variant=reader.text("variant"), network_config=config,
                       grid=GridRecord.from_dict(
                           reader.data.get("grid"),
                           lambda problem: reader.fail(f"its metadata {problem}")),
                       material_slots=tuple(
                           reader.array("material_slots", np.int64, (None,)).tolist()),
                       albedo_table=albedo_rows(albedo),
                       thresholds=Thresholds.read(reader.child("thresholds")),
                       train_poses=tuple(dict(pose) for pose in poses),
                       training=TrainingSummary.read(reader.child("training")),
                       dataset=DatasetSource.read(reader.child("dataset")),
                       vdnif_version=reader.text("vdnif_version"), version=version,
                       corners_follow=data.get("corners_follow", ARMATURE_COPY))
        except VDNIFError as exc:
            if str(exc).startswith(f"model file {path}"):
                raise
            reader.fail(str(exc))
        if (bad := first_non_plain(data)) is not None:     # the free-form entries (config)
            reader.fail(f"its metadata entry '{bad}' is not a finite number or plain data")
        return metadata

def outdated(path: str, version: object) -> str:
    """The one line that refuses a model file of another format version than this add-on's."""
    if isinstance(version, int) and version > FORMAT_VERSION:
        return (f"model file {path} has format version {version}, newer than this add-on "
                f"reads ({FORMAT_VERSION}); update the add-on")
    return (f"model file {path} has format version {shown(version)}, older than this add-on "
            f"reads ({FORMAT_VERSION}): train it again")
