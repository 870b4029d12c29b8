"""Training datasets: every walked segment with its targets, stored as shards.

A shard is ``<name>.npz`` (the arrays below, one row per segment) with ``<name>.json`` beside
it (grid, heads, poses, seeds, counts, versions). Separate processes write separate shards
(``--pose-range``) into one folder; training reads them all, lazily (``np.load`` of an npz
reads an array only when it is used).
"""

import json
import os
import pathlib
import zipfile

import numpy as np

from .errors import VDNIFError

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


def segment_records(grid, segments, targets, pose_index):
    """The shard rows for one pose's Segments and their SurfaceHits targets."""
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


def grid_header(grid):
    return {"origin": grid.origin.tolist(), "voxel_size": grid.voxel_size,
            "dims": grid.dims.tolist(), "resolution": grid.resolution, "extent": grid.extent,
            "occupied_voxels": int(len(grid.cells))}


def write_shard(folder, name, records, header):
    """Writes ``name.npz`` and ``name.json`` into ``folder`` atomically; returns the npz path."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    header = {"format": FORMAT, "version": VERSION, **header,
              "segments": int(len(records["pose"]))}
    target = folder / f"{name}.npz"
    partial = folder / f".{name}.partial.npz"
    np.savez(partial, **records)
    os.replace(partial, target)
    meta = folder / f".{name}.partial.json"
    meta.write_text(json.dumps(header, indent=1) + "\n")
    os.replace(meta, folder / f"{name}.json")
    return target


def read_dataset(folder):
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


def _read_header(path):
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


def _open_shard(path):
    try:
        shard = np.load(path)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise VDNIFError(f"dataset shard '{path}' cannot be read: {exc}") from None
    missing = set(ARRAYS) - set(shard.files)
    if missing:
        raise VDNIFError(f"dataset shard '{path}' lacks {', '.join(sorted(missing))}")
    return shard
