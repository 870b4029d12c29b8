"""The saved model: one file holding the weights, the network config and the scene's tables.

The file is a torch archive ``{"format", "version", "sha256", "payload"}`` whose payload is
itself a serialized ``{"network_config", "state_dict", "train_info", "extra"}``; the SHA-256
of the payload bytes catches corruption that the archive format alone would not. It is read
with ``weights_only=True`` only, so a foreign file cannot run code, and written atomically.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from ..errors import VDNIFError
from ..safe_io import atomic_path
from ..settings import OCCLUSION_THRESHOLD, NetworkConfig
from .network import IntersectionNetwork

if TYPE_CHECKING:
    from ..geometry.restmesh import RestMesh

FORMAT_NAME = "vdnif-model"
FORMAT_VERSION = 2
"""1: the hash-grid table feature-major, (Fd, rows). 2: row-major, (rows, Fd), as the encoder
kernel reads it; version 1 files are migrated on load."""

TABLE_KEY = "encoder.grid.table"
MAX_WEIGHT = 1e6
"""Trained weights stay within about +-10 (hash table entries start at 1e-4); a weight beyond
1e6 is damage and would overflow float32 activations into inf/NaN figures."""
GRID_KEYS = ("origin", "voxel_size", "dims", "resolution", "extent")


def mesh_fingerprint(mesh: RestMesh) -> str:
    """SHA-256 (hex) of a RestMesh's vertices, faces and materials: what a model was trained
    on, so that a mesh edited within the same bounds is told apart (``check_model_fits``)."""
    digest = hashlib.sha256()
    for array in (np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64),
                  np.asarray(mesh.material_index, np.int64),
                  np.asarray(mesh.material_slots, np.int64),
                  np.asarray(mesh.albedo_table(), np.float32)):
        digest.update(str(array.shape).encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


def _check_finite(path: str, value: Any, where: str) -> None:
    """Every number and numeric array in plain metadata finite (a NaN albedo table gave NaN
    figures downstream)."""
    if isinstance(value, dict):
        for key, item in value.items():
            _check_finite(path, item, f"{where}.{key}")
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_finite(path, item, f"{where}[{i}]")
    elif isinstance(value, (float, np.ndarray)) and not isinstance(value, bool):
        array = np.asarray(value)
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            raise VDNIFError(f"model file {path} is damaged: its metadata {where} has "
                             "non-finite values")


def check_scene_metadata(path: str | os.PathLike, extra: Any) -> None:
    """Raises VDNIFError unless the metadata ``extra`` of the model file ``path`` is that of a
    scene model as ``fit`` writes it: a complete grid of finite numbers with an integer
    resolution, a finite albedo table (the render and evaluation read them)."""
    path = os.fspath(path)
    if not isinstance(extra, dict):
        raise VDNIFError(f"model file {path} is damaged: its metadata is not a mapping")
    grid = extra.get("grid")
    if not isinstance(grid, dict) or any(key not in grid for key in GRID_KEYS):
        raise VDNIFError(f"model file {path} has no complete grid in its metadata "
                         f"({', '.join(GRID_KEYS)})")
    resolution = grid["resolution"]
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise VDNIFError(f"model file {path}: grid resolution {resolution!r} is not an integer")
    try:
        numbers = np.concatenate([np.asarray(grid[key], np.float64).ravel()
                                  for key in GRID_KEYS])
        table = np.asarray(extra.get("albedo_table", []), np.float64)
    except (TypeError, ValueError):
        raise VDNIFError(f"model file {path}: its grid or albedo table is not numbers") from None
    if not (np.isfinite(numbers).all() and np.isfinite(table).all()):
        raise VDNIFError(f"model file {path}: its grid or albedo table has non-finite values")
    if not (grid["voxel_size"] > 0 and grid["extent"] > 0):
        raise VDNIFError(f"model file {path}: grid voxel size and extent must be positive")


def _migrate(state_dict: dict[str, torch.Tensor], version: int) -> dict[str, torch.Tensor]:
    """A state dict of an older format version as the current network expects it."""
    if version < 2 and TABLE_KEY in state_dict:
        state_dict = dict(state_dict)
        state_dict[TABLE_KEY] = state_dict[TABLE_KEY].t().contiguous()
    return state_dict


def _storable(value: Any, where: str) -> Any:
    """Plain data that a weights-only load accepts (numpy arrays -> tensors, scalars ->
    numbers)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise VDNIFError(f"{where}: cannot store an array of dtype {value.dtype}")
        return torch.from_numpy(np.array(value))
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().clone()
    if isinstance(value, Mapping):
        if not all(isinstance(key, str) for key in value):
            raise VDNIFError(f"{where}: dictionary keys must be strings")
        return {key: _storable(item, f"{where}.{key}") for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_storable(item, f"{where}[{i}]") for i, item in enumerate(value))
    raise VDNIFError(f"{where}: cannot store a value of type {type(value).__name__}")


def _reason(exc: Exception) -> str:
    """The first line of an exception's message, for a one-line error."""
    lines = str(exc).strip().splitlines()
    return (lines[0] if lines else type(exc).__name__)[:200]


def _as_numpy(value: Any) -> Any:
    """Inverse of ``_storable`` for reading back: tensors become numpy arrays."""
    if isinstance(value, torch.Tensor):
        return value.numpy()
    if isinstance(value, dict):
        return {key: _as_numpy(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_as_numpy(item) for item in value)
    return value


def save_model(
    path: str | os.PathLike,
    network: IntersectionNetwork,
    network_config: NetworkConfig,
    train_info: Mapping[str, Any],
    extra: Mapping[str, Any],
) -> None:
    """Write ``network`` with its config and metadata to ``path``, atomically.

    ``train_info`` (how it was trained) and ``extra`` (grid, heads, material and albedo
    tables, ...) are plain data: dicts with string keys, lists, tuples, numbers, strings,
    None and numeric numpy arrays or tensors. The file is written to a temporary file in
    the same folder, fsynced and renamed over ``path``: a failed write leaves any existing
    file at ``path`` untouched and no temporary file behind.
    """
    path = os.fspath(path)
    if network.config != network_config:
        raise VDNIFError(
            f"cannot save {path}: the network was built with a different config than the one "
            "given"
        )
    inner = {
        "network_config": network_config.to_dict(),
        "state_dict": {
            key: value.detach().cpu().clone() for key, value in network.state_dict().items()
        },
        "train_info": _storable(train_info, "train_info"),
        "extra": _storable(extra, "extra"),
    }
    buffer = io.BytesIO()
    torch.save(inner, buffer)
    payload = buffer.getvalue()
    archive = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "sha256": hashlib.sha256(payload).hexdigest(),
        "payload": torch.frombuffer(bytearray(payload), dtype=torch.uint8),
    }
    with atomic_path(path, "model file", make_folder=False) as temporary:     # safe_io
        with open(temporary, "wb") as file:
            torch.save(archive, file)


def load_model(path: str | os.PathLike) -> tuple[IntersectionNetwork, dict[str, Any]]:
    """Read a model file: (network in eval mode on CPU, metadata).

    metadata: ``format``, ``version``, ``network_config`` (a NetworkConfig), ``train_info`` and
    ``extra`` (arrays come back as numpy arrays). A missing, corrupt, truncated, foreign or
    newer-format file raises VDNIFError naming the file.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise VDNIFError(f"model file {path} does not exist")
    try:
        archive = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        reason = (
            "not a plain-data torch archive"
            if isinstance(exc, pickle.UnpicklingError)
            else _reason(exc)
        )
        raise VDNIFError(
            f"model file {path} cannot be read (corrupt, truncated or not a VDNIF model): {reason}"
        ) from exc
    if not isinstance(archive, dict) or archive.get("format") != FORMAT_NAME:
        raise VDNIFError(f"{path} is not a VDNIF model file")
    version = archive.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise VDNIFError(f"model file {path} has an invalid format version {version!r}")
    if version > FORMAT_VERSION:
        raise VDNIFError(
            f"model file {path} has format version {version}, newer than this add-on reads "
            f"({FORMAT_VERSION}); update the add-on"
        )
    payload = archive.get("payload")
    if not isinstance(payload, torch.Tensor) or payload.dtype != torch.uint8:
        raise VDNIFError(f"model file {path} is corrupt: it has no payload")
    data = payload.numpy().tobytes()
    if hashlib.sha256(data).hexdigest() != archive.get("sha256"):
        raise VDNIFError(f"model file {path} is corrupt: its checksum does not match")
    try:
        inner = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
        stored = inner["network_config"]
        if isinstance(stored, dict) and "albedo_mode" not in stored:
            # Written before the albedo field: an albedo came from the head over the segment.
            stored = {**stored, "albedo_mode": "segment"}
        config = NetworkConfig.from_dict(stored)
        network = IntersectionNetwork(config)
        network.load_state_dict(_migrate(inner["state_dict"], version))
    except Exception as exc:
        raise VDNIFError(f"model file {path} is damaged: {_reason(exc)}") from exc
    network.eval()
    for key, value in network.state_dict().items():
        if value.is_floating_point() and not (torch.isfinite(value).all()
                                              and value.abs().max() <= MAX_WEIGHT):
            raise VDNIFError(f"model file {path} is damaged: weights '{key}' are not finite "
                             f"numbers of magnitude at most {MAX_WEIGHT:g}")
    extra = _as_numpy(inner.get("extra", {}))
    _check_finite(path, extra, "extra")
    # Files written before threshold calibration hold none: they were made for 0.5.
    network.occlusion_threshold = float(extra.get("occlusion_threshold", OCCLUSION_THRESHOLD))
    # Files written before the candidate threshold place the hit on the first segment above
    # the occlusion threshold, as they were evaluated.
    network.candidate_threshold = min(float(extra.get("candidate_threshold", 1.0)),
                                      network.occlusion_threshold)
    metadata = {
        "format": FORMAT_NAME,
        "version": version,
        "network_config": config,
        "train_info": _as_numpy(inner.get("train_info", {})),
        "extra": extra,
    }
    return network, metadata


def model_bytes(path: str | os.PathLike) -> int:
    """Size of the saved model file in bytes (the 'size' metric)."""
    try:
        return os.path.getsize(path)
    except OSError as exc:
        raise VDNIFError(f"model file {os.fspath(path)} cannot be read: {_reason(exc)}") from exc
