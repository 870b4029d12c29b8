"""A dataset shard's rows checked against their own points, and a shard read without
holding its file open (``dataset.read_dataset`` uses both)."""

from __future__ import annotations

import pathlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import VDNIFError
from ..safe_io import open_regular


class ClosedNpz(Mapping):
    """A checked npz shard read one array at a time, its file opened for each read and
    closed after it: a dataset of thousands of shards holds no file open between reads (an
    open-file limit of 1,024 refused a dataset of 2,000 valid shards)."""

    def __init__(self, path: pathlib.Path, files: tuple[str, ...]) -> None:
        self.path, self.files = path, files

    def __iter__(self) -> Any:
        return iter(self.files)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.files:
            raise KeyError(name)
        with open_regular(self.path, f"dataset shard '{self.path}'") as file:
            with np.load(file) as archive:
                return archive[name]


_LENGTH_TOLERANCE = 1e-3
"""Relative, with 1e-5 of the grid's extent besides: float32 rounding of normalized points
and lengths is ~1e-7 of the grid; a row off by more than this was not written by VDNIF."""


_NORMAL_TOLERANCE = 1e-2
"""Of a hit's unit normal's length: normals are stored in float16 (``packing``), whose
rounding moves a unit vector's length by at most ~1e-3."""


def check_lengths(path: pathlib.Path, arrays: dict[str, np.ndarray], extent: float) -> None:
    """Rows that disagree with their own points: a rest length other than the distance of
    p0 and p1 (in rest units, the grid's ``extent`` per normalized unit), a negative
    deformed length or ray distance, a hit whose normal is not of unit length. Training
    would learn from them without a word (a rest length of 0 reports a distance error of
    0, one of 3e38 overflows only when the model is saved)."""
    def refuse(name, reason):
        raise VDNIFError(f"dataset shard '{path}' array '{name}' {reason}: the shard is "
                         "damaged or was not written by VDNIF")

    if not len(arrays["p0"]):
        return
    for start in range(0, len(arrays["p0"]), _CHECK_ROWS):
        rows = slice(start, start + _CHECK_ROWS)
        expected = _norms(arrays["p1"][rows].astype(np.float64) - arrays["p0"][rows]) * extent
        rest = arrays["rest_len"][rows].astype(np.float64)
        off = np.abs(rest - expected) > _LENGTH_TOLERANCE * expected + 1e-5 * extent
        if off.any():
            row = int(np.argmax(off))
            refuse("rest_len", f"row {start + row} holds {rest[row]:.6g}, its points lie "
                               f"{expected[row]:.6g} apart")
    for name in ("seg_len", "t0"):
        if arrays[name].min() < 0:
            refuse(name, f"has negative values ({arrays[name].min():.6g})")
    hit = np.flatnonzero(arrays["hit"])
    for start in range(0, len(hit), _CHECK_ROWS):
        lengths = _norms(arrays["normal"][hit[start:start + _CHECK_ROWS]])
        if np.abs(lengths - 1).max() > _NORMAL_TOLERANCE:
            worst = lengths[int(np.argmax(np.abs(lengths - 1)))]
            refuse("normal", f"has a hit's normal of length {worst:.6g}, not 1")


_CHECK_ROWS = 1 << 16
"""Rows checked at once: a chunk's float64 temporaries stay in the cache, where the whole
shard's (hundreds of MB) cost page faults and passes over memory."""


def _norms(vectors: np.ndarray) -> np.ndarray:
    """Euclidean lengths of (N, 3) ``vectors``, in float64."""
    vectors = vectors.astype(np.float64)
    return np.sqrt(np.einsum("ij,ij->i", vectors, vectors))
