"""The saved model: one file holding the weights and the model's metadata.

The file is a torch archive ``{"format", "version", "sha256", "payload"}`` whose payload is
itself a serialized ``{"metadata", "state_dict"}``, the metadata as ``ModelMetadata.to_dict``
writes it; the SHA-256 of the payload bytes catches corruption that the archive format alone
would not. It is read with ``weights_only=True`` only, so a foreign file cannot run code, and
written atomically. A file of another format version than ``FORMAT_VERSION`` is refused.

``torch.save`` stores the members of its zip archive uncompressed, so a model file (and the
payload inside it) unpacks to no more bytes than it holds: one that claims more was not
written by VDNIF and is refused before torch allocates what its zip directory claims.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import VDNIFError
from ..safe_io import atomic_path, open_regular, shown, unpacked_size
from .metadata import FORMAT_VERSION, ModelMetadata, outdated
from .network import IntersectionNetwork

if TYPE_CHECKING:
    from ..geometry.restmesh import RestMesh

FORMAT_NAME = "vdnif-model"
MAX_WEIGHT = 1e6
"""Trained weights stay within about +-10 (hash table entries start at 1e-4); a weight beyond
1e6 is damage and would overflow float32 activations into inf/NaN figures."""


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


def texture_fingerprint(mesh: RestMesh) -> str | None:
    """SHA-256 (hex) of the images a RestMesh's materials read their albedo from (each
    material's kind, texture pixels and extension mode; a material without a texture counts
    as such), or None for a mesh without an image texture (its colours are in
    ``mesh_fingerprint``; its files stay as they were): a model trained on one texture is
    refused on another or on none. Kept apart from ``mesh_fingerprint``, which models
    written before it already store."""
    if not any(albedo.kind == "texture" for albedo in mesh.albedo):
        return None
    digest = hashlib.sha256()
    for albedo in mesh.albedo:
        digest.update(f"{albedo.kind}/{albedo.extension}".encode())
        texture = (np.zeros((0, 0, 3), np.float32) if albedo.texture is None
                   else np.asarray(albedo.texture, np.float32))
        digest.update(str(texture.shape).encode())
        digest.update(np.ascontiguousarray(texture).tobytes())
    return digest.hexdigest()


def _reason(exc: Exception) -> str:
    """The first line of an exception's message, for a one-line error."""
    lines = str(exc).strip().splitlines()
    return (lines[0] if lines else type(exc).__name__)[:200]


def save_model(
    path: str | os.PathLike, network: IntersectionNetwork, metadata: ModelMetadata
) -> None:
    """Write ``network`` with its ``metadata`` to ``path``, atomically.

    The network must be the one the metadata describes: built with its network config. The
    thresholds are the metadata's (their one record): the file keeps those, and
    ``load_model`` hands them to the network it reads. The file is written to a temporary
    file in the same folder, fsynced and renamed over ``path``: a failed write leaves any
    existing file at ``path`` untouched and no temporary file behind.
    """
    path = os.fspath(path)
    if network.config != metadata.network_config:
        raise VDNIFError(
            f"cannot save {path}: the network was built with a different config than the "
            "metadata's"
        )
    inner = {
        "metadata": metadata.to_dict(),
        "state_dict": {
            key: value.detach().cpu().clone() for key, value in network.state_dict().items()
        },
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
    buffer = io.BytesIO()
    torch.save(archive, buffer)
    # Written here, not by torch.save to the file: torch turns a failed write (a full disk)
    # into a RuntimeError of its own, where this write raises the OSError that names it.
    with atomic_path(path, "model file", make_folder=False, kind="model") as temporary:
        with open(temporary, "wb") as file:
            file.write(buffer.getbuffer())


def load_model(path: str | os.PathLike) -> tuple[IntersectionNetwork, ModelMetadata]:
    """Read a model file: (network in eval mode on CPU applying its metadata's thresholds,
    its metadata, checked). A missing, corrupt, truncated, foreign, damaged or other-format file
    raises a one-line VDNIFError naming the file."""
    path = os.fspath(path)
    with open_regular(path, f"model file {path}") as file:
        _check_unpacked(file, os.fstat(file.fileno()).st_size, path)
        archive = _read_archive(file, path)
    if not isinstance(archive, dict) or archive.get("format") != FORMAT_NAME:
        raise VDNIFError(f"{path} is not a VDNIF model file")
    version = archive.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise VDNIFError(f"model file {path} has an invalid format version {shown(version)}")
    if version != FORMAT_VERSION:
        raise VDNIFError(outdated(path, version))
    payload = archive.get("payload")
    if not isinstance(payload, torch.Tensor) or payload.dtype != torch.uint8:
        raise VDNIFError(f"model file {path} is corrupt: it has no payload")
    data = payload.numpy().tobytes()
    if hashlib.sha256(data).hexdigest() != archive.get("sha256"):
        raise VDNIFError(f"model file {path} is corrupt: its checksum does not match")
    _check_unpacked(io.BytesIO(data), len(data), path)
    try:
        inner = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
        stored = inner["metadata"]
        state_dict = inner["state_dict"]
    except Exception as exc:
        raise VDNIFError(f"model file {path} is damaged: {_reason(exc)}") from exc
    metadata = ModelMetadata.from_dict(stored, path)
    _check_weights_fit(path, metadata, state_dict)
    try:
        network = IntersectionNetwork(metadata.network_config)
        network.load_state_dict(state_dict)
    except Exception as exc:
        raise VDNIFError(f"model file {path} is damaged: {_reason(exc)}") from exc
    network.eval()
    for key, value in network.state_dict().items():
        if value.is_floating_point() and not (torch.isfinite(value).all()
                                              and value.abs().max() <= MAX_WEIGHT):
            raise VDNIFError(f"model file {path} is damaged: weights '{key}' are not finite "
                             f"numbers of magnitude at most {MAX_WEIGHT:g}")
    network.thresholds = metadata.thresholds
    return network, metadata


def _check_weights_fit(path: str, metadata: ModelMetadata, state_dict: object) -> None:
    """The weights' names and shapes against those of the network the metadata describes,
    found by building it on torch's "meta" device (shapes only, no memory): a small file
    whose metadata claims large tables is refused here, before the network is built (a
    10 KB file claiming 2^24-row tables built a 4.9 GB network first), and a mismatch is
    named in full, where ``load_state_dict`` lists every one on lines of their own."""
    if not isinstance(state_dict, dict) or not all(
            isinstance(key, str) and isinstance(value, torch.Tensor)
            for key, value in state_dict.items()):
        raise VDNIFError(f"model file {path} is damaged: its weights are not a mapping of "
                         "names to tensors")
    try:
        with torch.device("meta"):
            expected = IntersectionNetwork(metadata.network_config).state_dict()
    except Exception as exc:
        raise VDNIFError(f"model file {path} is damaged: {_reason(exc)}") from exc
    missing = [key for key in expected if key not in state_dict]
    unknown = [key for key in state_dict if key not in expected]
    if missing or unknown:
        names = [*(f"lacks '{key}'" for key in missing[:2]),
                 *(f"has an unknown '{key}'" for key in unknown[:2])]
        raise VDNIFError(f"model file {path} is damaged: its weights do not fit the network "
                         f"its metadata describes: it {' and '.join(names)}"
                         + (" (and more)" if len(missing) + len(unknown) > 2 else ""))
    for key, value in expected.items():
        stored = state_dict[key]
        if tuple(stored.shape) != tuple(value.shape):
            raise VDNIFError(
                f"model file {path} is damaged: weights '{key}' have shape "
                f"{tuple(stored.shape)}, the network its metadata describes needs "
                f"{tuple(value.shape)}")


def _read_archive(file: io.IOBase, path: str) -> object:
    """The torch archive in ``file`` (plain data and tensors only), or a one-line
    VDNIFError naming the model file ``path``."""
    try:
        return torch.load(file, map_location="cpu", weights_only=True)
    except Exception as exc:
        reason = ("not a plain-data torch archive" if isinstance(exc, pickle.UnpicklingError)
                  else _reason(exc))
        raise VDNIFError(f"model file {path} cannot be read (corrupt, truncated or not a "
                         f"VDNIF model): {reason}") from exc


def _check_unpacked(file: io.IOBase, size: int, path: str) -> None:
    """Raises VDNIFError when the zip archive ``file`` of ``size`` bytes would unpack to more
    than it holds (module docstring)."""
    unpacked = unpacked_size(file, f"model file {path}")
    if unpacked is not None and unpacked > size:
        raise VDNIFError(f"model file {path} is not a VDNIF model: it would unpack to "
                         f"{unpacked:,} bytes from {size:,} (VDNIF stores its members "
                         "uncompressed)")


def model_bytes(path: str | os.PathLike) -> int:
    """Size of the saved model file in bytes (the 'size' metric)."""
    try:
        return os.path.getsize(path)
    except OSError as exc:
        raise VDNIFError(f"model file {os.fspath(path)} cannot be read: {_reason(exc)}") from exc
