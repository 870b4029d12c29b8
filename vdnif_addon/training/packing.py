"""How a dataset shard stores its rows on disk: compactly where that is exact enough.

In memory a shard's rows are ``dataset.ARRAYS``, one row per segment. A shard of format
version 2 (``header.VERSION``) stores them so:

- the targets only a hit has (``HIT_ROWS``: zero on every other row) for its hit rows alone,
  in segment order; the reader puts the zeros back;
- ``albedo`` and ``material`` only where the dataset's heads have those heads; without them
  a hit's material is 0 and its albedo its material's row of the albedo table (the scene's
  albedo is constant per material, ``RestMesh.heads``), which the reader gives back;
- ``hit_frac``, ``normal`` and ``albedo`` in float16, ``pose`` in int16 (at most
  ``limits.MAX_POSES`` poses).

Why float16 there and nowhere else (rounding of the arm's recipe dataset, R = 32, against
what the metrics resolve there: a distance MAE of about 0.03 voxels, a normal error of about
2 degrees, an albedo PSNR of 25-35 dB): the hit's fraction along its segment moves the hit
by 5.5e-5 voxels on average (4e-4 at most); the normal turns by 0.001 degrees on average
(0.03 at most); an albedo in [0, 1] rounds to within 2.4e-4 (79 dB). The entry and exit
points would move by 0.003 voxels on average in float16 (0.009 at most), a tenth of the
distance error and more at a finer grid, so they stay float32, as do the lengths and ``t0``
(rest and deformed units, up to ``limits.MAX_OBJECT_SIZE``: beyond float16's range).

A version 1 shard (every array one row per segment, float32) is read as it is.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

import numpy as np

from ..errors import VDNIFError

if TYPE_CHECKING:
    from .header import DatasetHeads

HIT_ROWS = ("hit_frac", "normal", "albedo", "material")
"""The arrays a shard stores for its hit rows alone."""
STORED_TYPES = {"hit_frac": np.float16, "normal": np.float16, "albedo": np.float16,
                "pose": np.int16}
"""On-disk dtypes that differ from the rows' in memory (``dataset.ARRAYS``)."""


def stored_names(names: tuple[str, ...], heads: DatasetHeads) -> tuple[str, ...]:
    """The arrays of ``names`` (``dataset.ARRAYS``' order) that a shard with ``heads``
    stores."""
    return tuple(name for name in names if (name != "albedo" or heads.albedo)
                 and (name != "material" or heads.material))


def pack(records: Mapping[str, np.ndarray], heads: DatasetHeads) -> dict[str, np.ndarray]:
    """The arrays to store of a shard's rows ``records`` (``dataset.ARRAYS``)."""
    hit = np.asarray(records["hit"]) != 0
    stored = {}
    for name in stored_names(tuple(records), heads):
        array = np.asarray(records[name])
        if name in HIT_ROWS:
            array = array[hit]
        stored[name] = array.astype(STORED_TYPES.get(name, array.dtype), copy=False)
    return stored


class PackedShard(Mapping):
    """A version 2 shard's stored arrays (``archive``: its npz, read lazily) as the rows in
    memory, ``arrays`` (name: (dtype, trailing shape), ``dataset.ARRAYS``): each array read
    when it is asked for, a hit-only one spread over every row, one not stored for the
    dataset's ``heads`` made from its ``albedo_table``. An array stored with another kind of
    dtype or trailing shape than its row's is given as stored, for the reader's checks to
    name."""

    def __init__(self, archive: Mapping[str, np.ndarray], path: object,
                 arrays: Mapping[str, tuple[type, tuple[int, ...]]], heads: DatasetHeads,
                 albedo_table: tuple[tuple[float, float, float], ...]) -> None:
        self.archive, self.path, self.arrays = archive, path, arrays
        self.names, self.stored = tuple(arrays), stored_names(tuple(arrays), heads)
        self.albedo_table = np.asarray(albedo_table, arrays["albedo"][0])

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.names:
            raise KeyError(name)
        dtype, trailing = self.arrays[name]
        if name not in self.stored:
            hits, rows = self._hits(self["hit"])
            if name == "material":          # one material: every row's is 0
                return np.zeros(rows, dtype)
            material = np.clip(self["material"][hits], 0, len(self.albedo_table) - 1)
            return _spread(self.albedo_table[material], hits, rows, dtype, trailing)
        stored = self.archive[name]
        if stored.dtype.kind != np.dtype(dtype).kind or stored.shape[1:] != trailing:
            return stored
        if name not in HIT_ROWS:
            return stored.astype(dtype, copy=False)
        hit = self.archive["hit"]
        if hit.ndim != 1 or hit.dtype.kind not in "biu":
            return stored                   # the reader names what is wrong with 'hit'
        hits, rows = self._hits(hit)
        if len(stored) != len(hits):
            raise VDNIFError(f"dataset shard '{self.path}' array '{name}' has {len(stored)} "
                             f"rows, its 'hit' array {len(hits)} hits")
        return _spread(stored, hits, rows, dtype, trailing)

    @staticmethod
    def _hits(hit: np.ndarray) -> tuple[np.ndarray, int]:
        """(indices of the hit rows, rows) of a 'hit' array."""
        return np.flatnonzero(hit), len(hit)


def _spread(values: np.ndarray, hits: np.ndarray, rows: int, dtype: type,
            trailing: tuple[int, ...]) -> np.ndarray:
    """``values`` of the hit rows ``hits`` put into ``rows`` rows of zeros. By their indices:
    a shard's hits are a fifth of its millions of rows, and a boolean mask's assignment
    visits every row and took several times as long."""
    spread = np.zeros((rows, *trailing), dtype)
    spread[hits] = values
    return spread
