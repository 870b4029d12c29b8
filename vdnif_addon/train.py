"""Training: Adam with a decaying learning rate, validation on held-out poses, progress and
cooperative cancel, and data-parallel training when launched under ``torchrun``.

Data contract (the dataset module produces it): ``segments`` is a sequence of shards, each a
mapping of equal-length numpy arrays: ``p0``, ``p1`` (S, 3) normalized rest coordinates;
``seg_len``, ``rest_len`` (S,); ``hit`` (S,) uint8; ``hit_frac`` (S,) in [0,1]; ``normal``,
``albedo`` (S, 3); ``material`` (S,) int16; ``pose`` (S,) int32. ``header`` gives ``voxel_size``
(h, rest units) and ``heads`` = {"albedo": bool, "material_count": int}.

Non-finite values: training raises VDNIFError naming the step (1-based, before its update),
rather than skipping steps silently.
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from .errors import VDNIFError
from .losses import make_weighting, task_losses
from .network import IntersectionNetwork, readout
from .settings import OCCLUSION_THRESHOLD, Heads, NetworkConfig, TrainConfig

@dataclass
class TrainResult:
    """A trained network (eval mode, on the training device) and how training went."""

    network: IntersectionNetwork
    network_config: NetworkConfig
    config: TrainConfig
    status: str  # "completed" or "cancelled"
    steps: int  # optimizer steps taken
    validation: dict[str, float] | None  # on the held-out poses; None without any
    log_variances: dict[str, float]
    history: list[dict[str, Any]]
    seconds: float
    samples_per_s: float
    val_poses: list[int]
    occlusion_threshold: float = OCCLUSION_THRESHOLD  # calibrated on the held-out poses
    rank: int = 0
    world_size: int = 1

    @property
    def is_main(self) -> bool:
        """Only the main process (rank 0) writes outputs."""
        return self.rank == 0

    def info(self) -> dict[str, Any]:
        """Plain-data summary for ``model_file.save_model``'s ``train_info``."""
        return {
            "status": self.status,
            "steps": self.steps,
            "validation": self.validation,
            "log_variances": self.log_variances,
            "seconds": self.seconds,
            "samples_per_s": self.samples_per_s,
            "val_poses": self.val_poses,
            "occlusion_threshold": self.occlusion_threshold,
            "world_size": self.world_size,
            "config": self.config.to_dict(),
        }


# --------------------------------------------------------------------------- data

_FIELDS = {  # key -> (torch dtype, trailing shape)
    "p0": (torch.float32, (3,)),
    "p1": (torch.float32, (3,)),
    "rest_len": (torch.float32, ()),
    "hit": (torch.bool, ()),
    "hit_frac": (torch.float32, ()),
    "normal": (torch.float32, (3,)),
    "albedo": (torch.float32, (3,)),
    "material": (torch.int64, ()),
    "pose": (torch.int64, ()),
}


def load_segments(
    shards: Sequence[Mapping[str, np.ndarray]], heads: Heads, device: str | torch.device = "cpu"
) -> dict[str, torch.Tensor]:
    """Validate shards and concatenate the fields training uses into tensors on ``device``.

    Errors name the shard and field: missing or misshapen arrays, non-finite values,
    ``hit_frac`` outside [0,1], negative ``rest_len``, material indices outside [0, M) on hits.
    """
    keys = [
        key
        for key in _FIELDS
        if (key != "albedo" or heads.albedo) and (key != "material" or heads.material)
    ]
    if len(shards) == 0:
        raise VDNIFError("no training segments: the dataset has no shards")
    columns: dict[str, list[np.ndarray]] = {key: [] for key in keys}
    for number, shard in enumerate(shards):
        missing = [key for key in keys if key not in shard]
        if missing:
            raise VDNIFError(
                f"dataset shard {number} lacks {', '.join(repr(key) for key in missing)}"
            )
        arrays = {
            key: np.asarray(shard[key]) for key in keys
        }  # each read once (npz shards load lazily)
        length = arrays["p0"].shape[0] if arrays["p0"].ndim else 0
        for key, array in arrays.items():
            expected = (length,) + _FIELDS[key][1]
            if array.shape != expected:
                raise VDNIFError(
                    f"dataset shard {number} field '{key}' has shape {array.shape}, "
                    f"expected {expected}"
                )
            if array.dtype.kind == "f" and not np.isfinite(array).all():
                raise VDNIFError(f"dataset shard {number} field '{key}' has non-finite values")
            columns[key].append(array)
    data = {key: np.concatenate(arrays) for key, arrays in columns.items()}
    if data["p0"].shape[0] == 0:
        raise VDNIFError("no training segments: every shard is empty")
    hit = data["hit"] != 0
    if ((data["hit_frac"] < 0) | (data["hit_frac"] > 1)).any():
        raise VDNIFError("dataset field 'hit_frac' has values outside [0, 1]")
    if (data["rest_len"] < 0).any():
        raise VDNIFError("dataset field 'rest_len' has negative values")
    if (
        heads.material
        and ((data["material"][hit] < 0) | (data["material"][hit] >= heads.material_count)).any()
    ):
        raise VDNIFError(
            f"dataset field 'material' has indices outside [0, {heads.material_count}) on hits"
        )
    return {
        key: torch.from_numpy(np.ascontiguousarray(data[key])).to(
            device=device, dtype=_FIELDS[key][0]
        )
        for key in keys
    }


def _select(data: Mapping[str, torch.Tensor], index: torch.Tensor) -> dict[str, torch.Tensor]:
    return {key: value[index] for key, value in data.items()}


# --------------------------------------------------------------------------- evaluation

_SUMS = (
    "segments",
    "hits",
    "occlusion_loss",
    "occlusion_correct",
    "distance_loss",
    "distance_abs",
    "normal_loss",
    "normal_angle",
    "albedo_loss",
    "material_loss",
    "material_correct",
)


@torch.inference_mode()
def _evaluation_sums(
    network: IntersectionNetwork, data: Mapping[str, torch.Tensor], voxel_size: float, batch: int
) -> torch.Tensor:
    """Per-quantity sums over ``data`` in ``_SUMS`` order (summable across processes)."""
    mode = network.config.distance_mode
    sums = torch.zeros(len(_SUMS), dtype=torch.float64, device=data["p0"].device)
    for start in range(0, data["p0"].shape[0], batch):
        part = {key: value[start : start + batch] for key, value in data.items()}
        outputs = network(part["p0"], part["p1"])
        losses = task_losses(outputs, part, mode, voxel_size)
        predicted = readout(outputs, mode, voxel_size, part["rest_len"],
                            network.occlusion_threshold)
        hit = part["hit"]
        n, hits = hit.numel(), hit.sum()
        cos = (predicted["normal"] * part["normal"]).sum(1).clamp(-1.0, 1.0)
        terms = {
            "segments": torch.tensor(float(n)),
            "hits": hits,
            "occlusion_loss": losses["occlusion"] * n,
            "occlusion_correct": (predicted["hit"] == hit).sum(),
            "distance_loss": losses["distance"] * hits,
            "distance_abs": torch.where(
                hit, (predicted["distance"] - part["hit_frac"] * part["rest_len"]).abs(), 0.0
            ).sum(),
            "normal_loss": losses["normal"] * hits,
            "normal_angle": torch.where(hit, torch.rad2deg(torch.arccos(cos)), 0.0).sum(),
            "albedo_loss": losses["albedo"] * hits if "albedo" in losses else torch.tensor(0.0),
            "material_loss": losses["material"] * hits
            if "material" in losses
            else torch.tensor(0.0),
            "material_correct": torch.where(
                hit, predicted["material"] == part["material"], False
            ).sum()
            if "material" in losses
            else torch.tensor(0.0),
        }
        sums += torch.stack([terms[name].to(sums) for name in _SUMS])
    return sums


def _metrics(sums: torch.Tensor, voxel_size: float, heads: Heads) -> dict[str, float]:
    s = dict(zip(_SUMS, sums.tolist()))
    hits = max(s["hits"], 1.0)
    metrics = {
        "segments": s["segments"],
        "hits": s["hits"],
        "loss/occlusion": s["occlusion_loss"] / max(s["segments"], 1.0),
        "loss/distance": s["distance_loss"] / hits,
        "loss/normal": s["normal_loss"] / hits,
        "occlusion_accuracy": s["occlusion_correct"] / max(s["segments"], 1.0),
        "distance_mae": s["distance_abs"] / hits,
        "distance_mae_voxels": s["distance_abs"] / hits / voxel_size,
        "normal_error_deg": s["normal_angle"] / hits,
    }
    if heads.albedo:
        metrics["loss/albedo"] = s["albedo_loss"] / hits
    if heads.material:
        metrics["loss/material"] = s["material_loss"] / hits
        metrics["material_accuracy"] = s["material_correct"] / hits
    return metrics


def evaluate(
    network: IntersectionNetwork,
    data: Mapping[str, torch.Tensor],
    voxel_size: float,
    batch: int = 2**16,
) -> dict[str, float]:
    """Task losses and metrics of ``network`` on ``load_segments`` tensors.

    Hit-dependent metrics use the true hits: ``distance_mae`` (rest units; also in voxels),
    ``normal_error_deg``, ``material_accuracy``; ``occlusion_accuracy`` uses every segment.
    """
    return _metrics(
        _evaluation_sums(network, data, voxel_size, batch), voxel_size, network.config.heads
    )


# --------------------------------------------------------------------------- distributed


@dataclass
class _Distributed:
    """This process's place in a ``torchrun`` launch (world 1 when not launched so)."""

    rank: int = 0
    world: int = 1
    owns_group: bool = False

    @property
    def active(self) -> bool:
        return self.world > 1

    @classmethod
    def from_environment(cls, device: torch.device) -> _Distributed:
        try:
            world = int(os.environ.get("WORLD_SIZE", "1"))
        except ValueError as exc:
            raise VDNIFError(
                f"environment variable WORLD_SIZE is not an integer: {os.environ['WORLD_SIZE']!r}"
            ) from exc
        if world <= 1:
            return cls()
        owns = not dist.is_initialized()
        if owns:
            try:
                dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
            except (ValueError, RuntimeError) as exc:
                raise VDNIFError(
                    f"could not join the torchrun process group (WORLD_SIZE={world}): {exc}"
                ) from exc
        return cls(dist.get_rank(), dist.get_world_size(), owns)

    def max(self, values: torch.Tensor) -> torch.Tensor:
        """Elementwise maximum over processes (identity when alone)."""
        if self.active:
            dist.all_reduce(values, op=dist.ReduceOp.MAX)
        return values

    def sum(self, values: torch.Tensor) -> torch.Tensor:
        if self.active:
            dist.all_reduce(values)
        return values

    def union(self, items: list[int]) -> list[int]:
        if not self.active:
            return sorted(set(items))
        gathered: list[list[int] | None] = [None] * self.world
        dist.all_gather_object(gathered, items)
        return sorted({item for part in gathered for item in (part or [])})


def resolve_device(kind: str) -> torch.device:
    """ "auto" (CUDA if available, else CPU), "cpu" or "cuda" (this process's LOCAL_RANK device)."""
    if kind == "auto":
        kind = "cuda" if torch.cuda.is_available() else "cpu"
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise VDNIFError("setting device is 'cuda' but no CUDA device is available")
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    return torch.device("cpu")


# --------------------------------------------------------------------------- training


class Objective(nn.Module):
    """network + weighting: batch -> (total loss, per-task losses stacked in head order)."""

    def __init__(
        self, network: IntersectionNetwork, weighting: nn.Module, voxel_size: float
    ) -> None:
        super().__init__()
        self.network = network
        self.weighting = weighting
        self.voxel_size = voxel_size

    def forward(self, batch: Mapping[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        outputs = self.network(batch["p0"], batch["p1"])
        losses = task_losses(outputs, batch, self.network.config.distance_mode, self.voxel_size)
        return self.weighting(losses), torch.stack(list(losses.values()))


def _voxel_size(header: Mapping[str, Any]) -> float:
    """h from ``header['voxel_size']``, or ``header['grid']`` as the dataset module merges it."""
    if not isinstance(header, Mapping):
        raise VDNIFError(f"dataset header must be a mapping, got {type(header).__name__}")
    grid = header.get("grid")
    h = header.get("voxel_size", grid.get("voxel_size") if isinstance(grid, Mapping) else None)
    if isinstance(h, bool) or not isinstance(h, (int, float)) or not math.isfinite(h) or h <= 0:
        raise VDNIFError(f"dataset header 'voxel_size' must be a positive number, got {h!r}")
    return float(h)


def _split_poses(poses: torch.Tensor, fraction: float, seed: int, group: _Distributed) -> list[int]:
    """Held-out poses over all ranks: a seeded choice of round(fraction * poses), at least one."""
    everything = group.union(torch.unique(poses).tolist())
    if fraction == 0 or len(everything) < 2:
        return []
    count = min(max(round(fraction * len(everything)), 1), len(everything) - 1)
    order = torch.randperm(len(everything), generator=torch.Generator().manual_seed(seed))
    return sorted(everything[i] for i in order[:count].tolist())


def train(
    segments: Sequence[Mapping[str, np.ndarray]],
    header: Mapping[str, Any],
    config: TrainConfig,
    network_config: NetworkConfig,
    progress: Callable[[dict[str, Any]], None] | None = None,
    cancel: threading.Event | None = None,
) -> TrainResult:
    """Train an ``IntersectionNetwork`` on ``segments`` (see the module docstring).

    The heads follow ``header['heads']``. Every ``log_interval`` steps (and at the end) the main
    process calls ``progress`` with step, steps, mean task losses since the last call, total,
    log-variances, samples/s, ETA seconds and validation metrics on a fixed subset of the
    held-out poses. ``cancel`` (e.g. a threading.Event): once set, training stops before the
    next update and returns the model as it is, status "cancelled". Under ``torchrun``
    (WORLD_SIZE > 1) each rank trains on ``segments[rank::world]`` with gradients averaged by
    DistributedDataParallel; every rank returns the same weights.
    """
    voxel_size = _voxel_size(header)
    heads = Heads.from_header(header.get("heads", {}))
    network_config = dataclasses.replace(network_config, heads=heads)
    device = resolve_device(config.device)
    group = _Distributed.from_environment(device)
    try:
        return _train(segments, voxel_size, config, network_config, device, group, progress, cancel)
    finally:
        if group.owns_group:
            dist.destroy_process_group()


def _split_data(
    segments, config: TrainConfig, heads: Heads, device: torch.device, group: _Distributed
):
    """This process's shards, loaded and split into training and held-out-pose validation data."""
    if len(segments) == 0:
        raise VDNIFError("no training segments: the dataset has no shards")
    shards = list(segments)[group.rank :: group.world]
    if not shards:
        raise VDNIFError(
            f"process {group.rank} has no dataset shard: "
            f"{len(segments)} shards for {group.world} processes"
        )
    data = load_segments(shards, heads, device)
    val_poses = _split_poses(data["pose"], config.val_fraction, config.seed, group)
    held_out = torch.isin(data["pose"], torch.tensor(val_poses, dtype=torch.int64, device=device))
    train_data, val_data = _select(data, ~held_out), _select(data, held_out)
    if train_data["p0"].shape[0] == 0:
        raise VDNIFError(
            f"process {group.rank} has no training segments after holding out poses {val_poses}"
        )
    return train_data, val_data, val_poses


def _optimizer(
    objective: Objective, config: TrainConfig
) -> tuple[torch.optim.Adam, torch.optim.lr_scheduler.LambdaLR]:
    """Adam with instant-ngp's settings for the grid table, and an exponential lr decay.

    The fused Adam (one kernel over all of a group's parameters instead of a handful of
    tensor operations per parameter) computes the same update.
    """
    table = objective.network.encoder.grid.table
    others = [p for p in objective.parameters() if p is not table]
    optimizer = torch.optim.Adam(
        [
            {"params": [table], "lr": config.lr_grid, "eps": 1e-15},
            {"params": others, "lr": config.lr_mlp},
        ],
        betas=(0.9, 0.99),
        fused=True,
    )
    decay = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: config.final_lr_fraction ** (step / config.steps)
    )
    return optimizer, decay


class TrainingStep:
    """One optimizer step of ``train``: forward, losses, backward, the finite check and the
    cancel flag (one collective that every process answers alike), Adam, learning-rate decay.

    ``model`` is ``objective`` or its DistributedDataParallel wrapper. Calling it with a batch
    returns (cancelled, total loss, task losses); a non-finite loss or gradient raises
    VDNIFError naming the step (1-based, before its update).
    """

    def __init__(self, objective: Objective, config: TrainConfig, model: nn.Module | None = None,
                 group: _Distributed | None = None) -> None:
        self.model = model or objective
        self.group = group or _Distributed()
        self.optimizer, self.decay = _optimizer(objective, config)
        self.params = list(objective.parameters())
        self.tasks = list(objective.network.head_sizes)
        self.taken = 0

    def __call__(self, batch: Mapping[str, torch.Tensor], cancel: threading.Event | None = None
                 ) -> tuple[bool, torch.Tensor, torch.Tensor]:
        total, losses = self.model(batch)
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        grad_norm = torch.nn.utils.get_total_norm(
            [p.grad for p in self.params if p.grad is not None]
        )
        requested = torch.tensor(cancel is not None and cancel.is_set(), device=total.device)
        flags = torch.stack(
            [~(torch.isfinite(total) & torch.isfinite(grad_norm)), requested]
        ).float()
        diverged, cancelled = self.group.max(flags).tolist()
        if diverged:
            detail = ", ".join(
                f"{task}={value:.4g}" for task, value in zip(self.tasks, losses.tolist())
            )
            raise VDNIFError(
                f"training stopped at step {self.taken + 1}: "
                f"the loss or its gradient is not finite ({detail})"
            )
        if cancelled:
            return True, total, losses
        self.optimizer.step()
        self.decay.step()
        self.taken += 1
        return False, total, losses


def _train(
    segments, voxel_size, config, network_config, device, group, progress, cancel
) -> TrainResult:
    train_data, val_data, val_poses = _split_data(
        segments, config, network_config.heads, device, group
    )
    sampler = torch.Generator(device=device).manual_seed(config.seed + group.rank)
    probe = _select(
        val_data,
        torch.randperm(val_data["p0"].shape[0], generator=sampler, device=device)[
            : config.val_segments
        ],
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        network = IntersectionNetwork(network_config)
    weighting = make_weighting(config.weighting, list(network.head_sizes))
    objective = Objective(network, weighting, voxel_size).to(device)
    model = (
        nn.parallel.DistributedDataParallel(objective, broadcast_buffers=False)
        if group.active
        else objective
    )
    step_once = TrainingStep(objective, config, model, group)
    tasks = step_once.tasks
    samples_per_step = config.batch_size * group.world

    status, history = "completed", []
    running = torch.zeros(
        1 + len(tasks), device=device
    )  # summed total and task losses since the last report
    window_steps, window_seconds, train_seconds, steps_done = 0, 0.0, 0.0, 0
    for _ in range(config.steps):
        started = time.perf_counter()
        batch = _select(
            train_data,
            torch.randint(
                train_data["p0"].shape[0], (config.batch_size,), generator=sampler, device=device
            ),
        )
        cancelled, total, losses = step_once(batch, cancel)
        if cancelled:
            status = "cancelled"
            break
        steps_done += 1
        running += torch.cat([total.detach()[None], losses.detach()])
        elapsed = time.perf_counter() - started
        window_steps, window_seconds, train_seconds = (
            window_steps + 1,
            window_seconds + elapsed,
            train_seconds + elapsed,
        )
        if steps_done % config.log_interval == 0 or steps_done == config.steps:
            means = (running / window_steps).tolist()
            rate = window_steps * samples_per_step / max(window_seconds, 1e-9)
            record = {
                "step": steps_done,
                "steps": config.steps,
                "total": means[0],
                "losses": dict(zip(tasks, means[1:])),
                "log_variances": weighting.log_variances(),
                "samples_per_s": rate,
                "eta_s": (config.steps - steps_done) * samples_per_step / rate,
                "validation": _validate(network, probe, voxel_size, group),
            }
            history.append(record)
            if progress is not None and group.rank == 0:
                progress(record)
            running.zero_()
            window_steps, window_seconds = 0, 0.0

    network.eval()
    threshold = calibrate_threshold(network, val_data, group)
    network.occlusion_threshold = threshold
    return TrainResult(
        network=network,
        network_config=network_config,
        config=config,
        status=status,
        steps=steps_done,
        validation=_validate(network, val_data, voxel_size, group),
        log_variances=weighting.log_variances(),
        history=history,
        seconds=train_seconds,
        samples_per_s=steps_done * samples_per_step / max(train_seconds, 1e-9),
        val_poses=val_poses,
        occlusion_threshold=threshold,
        rank=group.rank,
        world_size=group.world,
    )


# Candidate thresholds: 0.02 apart, so that a probability histogram of THRESHOLD_BINS bins
# summed over processes counts the errors of each exactly.
THRESHOLD_BINS = 50
THRESHOLD_RANGE = (0.1, 0.9)


@torch.inference_mode()
def calibrate_threshold(
    network: IntersectionNetwork,
    data: Mapping[str, torch.Tensor],
    group: _Distributed | None = None,
    batch: int = 2**16,
) -> float:
    """The occlusion threshold that misclassifies the fewest segments of ``data`` (the
    held-out poses), among the multiples of 1/THRESHOLD_BINS in THRESHOLD_RANGE; ties go to
    the one nearest OCCLUSION_THRESHOLD, and without held-out segments it is
    OCCLUSION_THRESHOLD. A hole is a hit segment below the threshold, an extra a miss
    segment above it (DESIGN section 9)."""
    group = group or _Distributed()
    device = data["p0"].device
    counts = torch.zeros(2, THRESHOLD_BINS, dtype=torch.float64, device=device)
    for start in range(0, data["p0"].shape[0], batch):
        outputs = network(data["p0"][start : start + batch], data["p1"][start : start + batch])
        probability = torch.sigmoid(outputs["occlusion"].float())
        bins = (probability * THRESHOLD_BINS).long().clamp(0, THRESHOLD_BINS - 1)
        hit = data["hit"][start : start + batch].long()
        counts.index_put_((hit, bins), torch.ones_like(probability, dtype=torch.float64),
                          accumulate=True)
    counts = group.sum(counts)
    if counts.sum() == 0:
        return OCCLUSION_THRESHOLD
    # Threshold k / BINS: hits in bins below k are holes, misses in bins k and up extras.
    holes = torch.cat([counts.new_zeros(1), counts[1].cumsum(0)])
    extras = counts[0].sum() - torch.cat([counts.new_zeros(1), counts[0].cumsum(0)])
    errors = (holes + extras).tolist()
    low, high = (round(edge * THRESHOLD_BINS) for edge in THRESHOLD_RANGE)
    best = min(range(low, high + 1),
               key=lambda k: (errors[k], abs(k / THRESHOLD_BINS - OCCLUSION_THRESHOLD)))
    return best / THRESHOLD_BINS


def _validate(
    network: IntersectionNetwork,
    data: Mapping[str, torch.Tensor],
    voxel_size: float,
    group: _Distributed,
) -> dict[str, float] | None:
    """Metrics on held-out data summed over processes; None when no process holds any."""
    was_training = network.training
    network.eval()
    sums = group.sum(_evaluation_sums(network, data, voxel_size, 2**16))
    network.train(was_training)
    return _metrics(sums, voxel_size, network.config.heads) if sums[0] > 0 else None
