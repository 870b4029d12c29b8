"""Training data: dataset shards -> validated tensors, this process's share of them, the
held-out poses, and the random batches the loop draws.

The training rows move to the training GPU where they take at most
``memory.DEVICE_ROWS_SHARE`` of its free memory, and each step's batch is gathered there
(only its row indices go from the host); elsewhere (a dataset may be many times a GPU's
memory) they stay in host memory, and each step's batch is gathered there and moved to the
training device.
The held-out rows, a ``val_fraction`` of them that validation evaluates in chunks, live on
the device.

Data contract (the dataset module produces it): ``segments`` is a sequence of shards, each a
mapping of equal-length numpy arrays: ``p0``, ``p1`` (S, 3) normalized rest coordinates;
``seg_len``, ``rest_len`` (S,); ``hit`` (S,) uint8; ``hit_frac`` (S,) in [0,1]; ``normal``,
``albedo`` (S, 3); ``material`` (S,) int16; ``pose``, ``ray`` (S,) int32; ``t0`` (S,) the
deformed distance to the segment's entry; a ray's segments in walk order. Their dataset
header (``header.DatasetHeader``) gives the voxel size h (rest units) and the heads.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from concurrent.futures import Future
from typing import TYPE_CHECKING

import numpy as np
import torch

from .. import memory, threads
from ..errors import VDNIFError
from ..settings import Heads, TrainConfig
from .distributed import ProcessGroup

if TYPE_CHECKING:
    from jaxtyping import Bool, Int64, Shaped

Segments = dict[str, "Shaped[torch.Tensor, 'segments ...']"]
"""Field name -> tensor of one row per segment (``FIELDS`` gives dtype and trailing shape)."""

FIELDS = {  # key -> (torch dtype, trailing shape)
    "p0": (torch.float32, (3,)),
    "p1": (torch.float32, (3,)),
    "rest_len": (torch.float32, ()),
    "hit": (torch.bool, ()),
    "hit_frac": (torch.float32, ()),
    "normal": (torch.float32, (3,)),
    "albedo": (torch.float32, (3,)),
    "material": (torch.int64, ()),
    "pose": (torch.int64, ()),
    "ray": (torch.int64, ()),
    "t0": (torch.float32, ()),
    "seg_len": (torch.float32, ()),
}
RAY_FIELDS = ("ray", "t0", "seg_len")
"""Where a segment lies on its ray: only the held-out data keeps them, for calibrating where
hits are placed (``validation.calibrate_candidate_threshold``)."""


def load_segments(
    shards: Sequence[Mapping[str, np.ndarray]], heads: Heads, device: str | torch.device = "cpu"
) -> Segments:
    """Validate shards and concatenate the fields training uses into tensors on ``device``.

    Errors name the shard and field: missing or misshapen arrays, non-finite values,
    ``hit_frac`` outside [0,1], negative ``rest_len``, material indices outside [0, M) on hits.
    """
    arrays = _read_shards(shards, heads)
    everything = [None] * len(arrays)
    return {key: _column(arrays, key, everything).to(device) for key in arrays[0]}


def _read_shards(
    shards: Sequence[Mapping[str, np.ndarray]], heads: Heads
) -> list[dict[str, np.ndarray]]:
    """The fields training uses of every shard, each read once (npz shards load lazily) and
    validated (``load_segments`` says how)."""
    keys = [
        key
        for key in FIELDS
        if (key != "albedo" or heads.albedo) and (key != "material" or heads.material)
    ]
    if len(shards) == 0:
        raise VDNIFError("no training segments: the dataset has no shards")
    out = []
    for number, shard in enumerate(shards):
        missing = [key for key in keys if key not in shard]
        if missing:
            raise VDNIFError(
                f"dataset shard {number} lacks {', '.join(repr(key) for key in missing)}"
            )
        arrays = {key: np.asarray(shard[key]) for key in keys}
        length = arrays["p0"].shape[0] if arrays["p0"].ndim else 0
        for key, array in arrays.items():
            expected = (length,) + FIELDS[key][1]
            if array.shape != expected:
                raise VDNIFError(
                    f"dataset shard {number} field '{key}' has shape {array.shape}, "
                    f"expected {expected}"
                )
            if array.dtype.kind == "f" and not np.isfinite(array).all():
                raise VDNIFError(f"dataset shard {number} field '{key}' has non-finite values")
        out.append(arrays)
    if sum(len(arrays["p0"]) for arrays in out) == 0:
        raise VDNIFError("no training segments: every shard is empty")
    for arrays in out:
        if ((arrays["hit_frac"] < 0) | (arrays["hit_frac"] > 1)).any():
            raise VDNIFError("dataset field 'hit_frac' has values outside [0, 1]")
        if (arrays["rest_len"] < 0).any():
            raise VDNIFError("dataset field 'rest_len' has negative values")
        hit = arrays["hit"] != 0
        if heads.material and (
            (arrays["material"][hit] < 0) | (arrays["material"][hit] >= heads.material_count)
        ).any():
            raise VDNIFError(
                f"dataset field 'material' has indices outside [0, {heads.material_count}) "
                "on hits"
            )
    return out


def _column(arrays: list[dict[str, np.ndarray]], key: str,
            rows: Sequence[Int64[torch.Tensor, " chosen"] | None]) -> torch.Tensor:
    """A host tensor of ``FIELDS``' dtype for field ``key`` holding the rows ``rows[i]``
    (indices, ``_chosen``; None: every row) of every shard ``arrays[i]``, in shard order.
    Written once, shard by shard: a dataset is gigabytes, and a first write to fresh memory
    costs more than the copy itself. Gathered by torch's ``index_select``: numpy's boolean
    masks took ten times as long on a dataset of 30 M rows."""
    dtype, trailing = FIELDS[key]
    counts = [len(shard[key]) if index is None else len(index)
              for shard, index in zip(arrays, rows)]
    column = torch.empty((sum(counts), *trailing), dtype=dtype)
    start = 0
    for shard, index, count in zip(arrays, rows, counts):
        source = torch.from_numpy(np.require(shard[key], requirements=("C", "W")))
        target = column[start : start + count]
        if index is None:
            target.copy_(source)
        elif source.dtype == dtype:
            torch.index_select(source, 0, index, out=target)
        else:                       # stored narrower (uint8 hits, int32 poses): convert
            target.copy_(torch.index_select(source, 0, index))
        start += count
    return column


def _chosen(mask: Bool[np.ndarray, " segments"]) -> Int64[torch.Tensor, " chosen"] | None:
    """The indices of a shard's rows that ``mask`` keeps, for ``_column`` (None: all)."""
    return None if mask.all() else torch.from_numpy(np.flatnonzero(mask))


def select(data: Mapping[str, torch.Tensor], index: Int64[torch.Tensor, " chosen"]) -> Segments:
    """The rows ``index`` of every field."""
    return {key: value[index] for key, value in data.items()}


def held_out_count(poses: int, fraction: float) -> int:
    """How many of ``poses`` poses ``split_poses`` holds out: round(fraction * poses), at
    least one and one fewer than all; none of fewer than two or at fraction 0."""
    if fraction == 0 or poses < 2:
        return 0
    return min(max(round(fraction * poses), 1), poses - 1)


def split_poses(
    poses: Int64[torch.Tensor, " segments"], fraction: float, seed: int, group: ProcessGroup
) -> list[int]:
    """Held-out poses over all ranks: a seeded choice of round(fraction * poses), at least one."""
    everything = group.union(torch.unique(poses).tolist())
    count = held_out_count(len(everything), fraction)
    if count == 0:
        return []
    order = torch.randperm(len(everything), generator=torch.Generator().manual_seed(seed))
    return sorted(everything[i] for i in order[:count].tolist())


def held_out_rays(
    ray: Int64[torch.Tensor, " segments"], fraction: float, seed: int
) -> Bool[torch.Tensor, " segments"]:
    """The rows of about ``fraction`` of the rays, whole rays chosen alike in every process:
    those whose id times the golden ratio, shifted by the seed, has a fractional part below
    ``fraction``. A dataset of one pose (``lsnif``'s) holds these out instead of a pose, so
    that its thresholds are calibrated on held-out rays as the others' are on held-out poses."""
    golden = (5**0.5 - 1) / 2
    return torch.frac(ray.double() * golden + seed * 2**-0.5) < fraction


def split_data(
    segments: Sequence[Mapping[str, np.ndarray]],
    config: TrainConfig,
    heads: Heads,
    device: torch.device,
    group: ProcessGroup,
    view_from: int | None = None,
) -> tuple[TrainingRows | Segments, Segments, Segments, list[int]]:
    """(training rows, on ``device`` where they fit (``_on_device_where_room``) and else in
    host memory, validation data on ``device``, the held-out calibration view's rows on
    ``device``, held-out poses): this process's shards
    (``segments[rank::world]``) loaded and split by the held-out poses, or, with one pose, by
    held-out rays (``held_out_rays``; no pose is then held out). Rows of rays numbered
    ``view_from`` and up are the calibration view's (``settings.CALIBRATION_VIEW_SHARE``):
    never trained on, the held-out ones kept apart from the validation data."""
    if len(segments) == 0:
        raise VDNIFError("no training segments: the dataset has no shards")
    shards = list(segments)[group.rank :: group.world]
    if not shards:
        raise VDNIFError(
            f"process {group.rank} has no dataset shard: "
            f"{len(segments)} shards for {group.world} processes"
        )
    arrays = _read_shards(shards, heads)
    poses = np.concatenate([np.unique(shard["pose"]) for shard in arrays])
    val_poses = split_poses(torch.from_numpy(poses).long(), config.val_fraction, config.seed,
                            group)
    held_out = [np.isin(shard["pose"], val_poses) if val_poses else
                held_out_rays(torch.from_numpy(shard["ray"]).long(), config.val_fraction,
                              config.seed).numpy() for shard in arrays]
    view = [shard["ray"] >= view_from if view_from is not None
            else np.zeros(len(shard["ray"]), bool) for shard in arrays]
    kept = [~(mask | seen) for mask, seen in zip(held_out, view)]
    if not any(mask.any() for mask in kept):
        rows = sum(len(mask) for mask in kept)
        whose = ("the dataset" if group.world == 1 else f"process {group.rank}'s shards")
        if rows == 0:
            raise VDNIFError(f"{whose} hold no segments: make a dataset whose rays meet "
                             "the object")
        whose = f"the {rows:,} segments of {whose}"
        held = (f"the poses {val_poses}" if val_poses else
                f"{config.val_fraction:g} of the rays of its one pose")
        raise VDNIFError(f"{whose} leave none to train on once {held} are held out for "
                         "validation: make a dataset with more rays (--rays-per-pose) or "
                         "poses")
    train_rows, val_data, view_data = TrainingRows(device), {}, {}
    validated = [_chosen(mask & ~seen) for mask, seen in zip(held_out, view)]
    calibrating = [_chosen(mask & seen) for mask, seen in zip(held_out, view)]
    kept = [_chosen(mask) for mask in kept]

    def columns(key: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Field ``key``'s validation, calibration-view and training columns (the copies
        release the GIL: two fields are gathered at once, ``COLUMNS_AT_ONCE``)."""
        return (_column(arrays, key, validated), _column(arrays, key, calibrating),
                None if key in RAY_FIELDS else _column(arrays, key, kept))

    keys = list(arrays[0])
    for key, (validation, calibration, training) in zip(
            keys, threads.in_order(keys, columns, COLUMNS_AT_ONCE, "vdnif-split")):
        val_data[key] = validation.to(device)
        view_data[key] = calibration.to(device)
        if training is not None:
            train_rows[key] = training
        for shard in arrays:        # a field at a time: no second copy of the whole data
            del shard[key]
    return _on_device_where_room(train_rows), val_data, view_data, val_poses


COLUMNS_AT_ONCE = 2
"""Fields ``split_data`` gathers at once, each on a thread: a column's copy into fresh memory
waits on memory, and two overlap."""


def _on_device_where_room(rows: TrainingRows) -> TrainingRows | Segments:
    """``rows`` moved to their training device, one field at a time, where they take at most
    ``memory.DEVICE_ROWS_SHARE`` of its free memory (``memory.device_free_bytes``); else as
    they are, in host memory."""
    free = memory.device_free_bytes(rows.device)
    size = sum(value.numel() * value.element_size() for value in rows.values())
    if free is None or size > memory.DEVICE_ROWS_SHARE * free:
        return rows
    return {key: rows.pop(key).to(rows.device) for key in list(rows)}


class TrainingRows(dict):
    """Segments in host memory, with the ``device`` that their batches train on."""

    def __init__(self, device: str | torch.device) -> None:
        super().__init__()
        self.device = torch.device(device)


class Batches:
    """Random batches of one process's training data, drawn by a seeded generator in host
    memory (seed + rank: each process draws its own batches) and moved to the training device
    (``TrainingRows.device``; plain Segments train where they are).

    Rows in host memory are gathered one batch ahead on a thread of their own: a gather of
    random rows out of gigabytes waits on memory, so it runs while the step before computes.
    The indices are drawn on the caller's thread in the same order as without it, so the
    batches are the same."""

    def __init__(self, data: Segments, batch_size: int, seed: int) -> None:
        self.data = data
        self.batch_size = batch_size
        self.count = data["p0"].shape[0]
        self.device = getattr(data, "device", data["p0"].device)
        self.generator = torch.Generator().manual_seed(seed)
        self._ahead: Future | None = None

    def subset(self, data: Segments, size: int) -> Segments:
        """At most ``size`` rows of ``data`` drawn without replacement (the validation
        probe), from this generator, on the device of ``data``."""
        order = torch.randperm(data["p0"].shape[0], generator=self.generator)
        return select(data, order[:size].to(data["p0"].device))

    def next(self) -> Segments:
        """``batch_size`` rows drawn with replacement, on the training device."""
        if self.data["p0"].device.type != "cpu":
            return select(self.data, self._index().to(self.data["p0"].device))
        if self._ahead is None:
            self._ahead = threads.launch_pool(1).submit(self._gather, self._index())
        rows = self._ahead.result()
        self._ahead = threads.launch_pool(1).submit(self._gather, self._index())
        return {key: value.to(self.device, non_blocking=True) for key, value in rows.items()}

    def _index(self) -> Int64[torch.Tensor, " batch"]:
        return torch.randint(self.count, (self.batch_size,), generator=self.generator)

    def _gather(self, index: Int64[torch.Tensor, " batch"]) -> Segments:
        """Host rows ``index``; in page-locked memory where they go to a GPU."""
        if self.device.type == "cuda":
            return {key: _staged(value, index) for key, value in self.data.items()}
        return select(self.data, index)


def _staged(column: torch.Tensor, index: Int64[torch.Tensor, " chosen"]) -> torch.Tensor:
    """Rows ``index`` of a host column gathered into page-locked memory, whose copy to the GPU
    neither waits for the GPU nor holds up the host (torch's pinned allocator keeps a block
    until the copy that reads it is done)."""
    staged = torch.empty((len(index), *column.shape[1:]), dtype=column.dtype, pin_memory=True)
    return torch.index_select(column, 0, index, out=staged)
