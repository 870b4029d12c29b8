"""Training: Adam with a decaying learning rate, validation on held-out poses, progress and
cooperative cancel, and data-parallel training when launched under ``torchrun``.

The data (``training.data``: its module docstring gives the contract), the held-out metrics
and threshold (``validation``), the progress records (``training.log``) and the process
group (``distributed``) have modules of their own; this one holds the loop.

Non-finite values: training raises VDNIFError naming the step (1-based, before its update),
rather than skipping steps silently; it finds out at the next progress record (or cancel),
and applies no update from that step on (``TrainingStep``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import nn

from .. import threads
from ..errors import VDNIFError
from ..limits import GROUP_TIMEOUT_S
from ..model.encoding import HashGrid
from ..model.metadata import Thresholds, TrainingSummary
from ..model.network import IntersectionNetwork, resolve_precision, sized_to_scene
from ..settings import OCCLUSION_THRESHOLD, NetworkConfig, TrainConfig
from .data import Batches, Segments, split_data
from .distributed import ProcessGroup, resolve_device
from .header import DatasetHeader
from .log import ProgressLog, record_due
from .losses import make_weighting, task_losses
from .stopping import StoppingRule
from .validation import (
    calibrate_candidate_threshold,
    calibrate_threshold,
    head_outputs,
    validate,
)

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int64


@dataclass
class TrainResult:
    """A trained network (eval mode, on the training device, holding the thresholds
    calibrated on the held-out poses) and how training went."""

    network: IntersectionNetwork
    network_config: NetworkConfig
    config: TrainConfig
    status: str  # "completed" (every step), "converged" (the stopping rule) or "cancelled"
    steps: int  # optimizer steps taken
    validation: dict[str, float] | None  # on the held-out poses; None without any
    log_variances: dict[str, float]
    history: list[dict[str, Any]]
    seconds: float
    samples_per_s: float
    val_poses: list[int]
    rank: int = 0
    world_size: int = 1
    # Wall seconds of the work around the steps and the rows it covered (what an estimate
    # scales): split_s (the shards into training and held-out rows), validation_s over
    # ``validations`` validations of probe_rows rows each, final_s (the held-out outputs,
    # the thresholds' calibration and the last validation over held_out_rows rows).
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def is_main(self) -> bool:
        """Only the main process (rank 0) writes outputs."""
        return self.rank == 0

    @property
    def thresholds(self) -> Thresholds:
        """The thresholds calibrated on the held-out poses (the network's)."""
        return self.network.thresholds

    def summary(self) -> TrainingSummary:
        """How training went, as the model's metadata keeps it (``info`` in numbers of the
        metadata's types)."""
        def numbers(values: Mapping[str, Any]) -> dict[str, float | None]:
            return {name: None if value is None else float(value)
                    for name, value in values.items()}

        return TrainingSummary(
            status=self.status, steps=int(self.steps), seconds=float(self.seconds),
            samples_per_s=float(self.samples_per_s),
            validation=None if self.validation is None else numbers(self.validation),
            log_variances=numbers(self.log_variances),
            val_poses=tuple(int(index) for index in self.val_poses),
            world_size=int(self.world_size), config=self.config.to_dict())

    def info(self) -> dict[str, Any]:
        """Plain-data summary, the model metadata's ``training`` entry
        (``metadata.TrainingSummary``)."""
        return {
            "status": self.status,
            "steps": self.steps,
            "validation": self.validation,
            "log_variances": self.log_variances,
            "seconds": self.seconds,
            "samples_per_s": self.samples_per_s,
            "val_poses": self.val_poses,
            "world_size": self.world_size,
            "config": self.config.to_dict(),
        }


class Objective(nn.Module):
    """network + weighting: batch -> (total loss, per-task losses stacked in head order).

    In training mode the point fields (``IntersectionNetwork.point_fields``) learn at the
    reference's hit moved along the segment by N(0, ``field_jitter`` voxels), drawn from a
    generator of its own (``seed``): read at the hit the network places, off by its distance
    error, they answer as at the surface.

    The fields are read on the first ``field_rows`` rows of a batch ordered hits first (the
    module's ``field_rows``), not on every row: only the hits' losses read them, and a
    batch's hit count is not known on the host without waiting for the device.

    ``precision`` is the MLPs' arithmetic, "float32" or "bfloat16" (resolved:
    ``model.network.resolve_precision``): in bfloat16 their layers multiply in it forward
    and backward, while the hash grids, the losses, the weights, their gradients and Adam
    stay float32."""

    def __init__(
        self, network: IntersectionNetwork, weighting: nn.Module, voxel_size: float,
        field_jitter: float = 0.0, seed: int = 0, field_rows: int | None = None,
        precision: str = "float32",
    ) -> None:
        super().__init__()
        if precision not in ("float32", "bfloat16"):
            raise VDNIFError(f"the objective's MLPs run in float32 or bfloat16, not "
                             f"'{precision}'")
        self.precision = precision
        self.network = network
        self.weighting = weighting
        self.voxel_size = voxel_size
        self.field_jitter = field_jitter
        self.field_rows = field_rows
        self.seed = seed
        self._jitter: torch.Generator | None = None   # on the batch's device, at first use

    def forward(
        self, batch: Segments
    ) -> tuple[Float[torch.Tensor, ""], Float[torch.Tensor, " tasks"]]:
        """(total loss, task losses in head order) of ``batch``."""
        at = batch["hit_frac"]
        if self.training and self.field_jitter > 0 and self.network.point_fields():
            shift = self.field_jitter * self.voxel_size / batch["rest_len"].clamp_min(1e-30)
            if self._jitter is None:
                self._jitter = torch.Generator(at.device).manual_seed(self.seed)
            at = at + torch.randn(at.shape, generator=self._jitter, device=at.device) * shift
        rows = None
        if self.field_rows is not None and self.field_rows < len(at):
            rows = hits_first(batch["hit"])[:self.field_rows]
        # the network hands its heads and fields on in float32 (``heads``, ``PointField``)
        with torch.autocast(at.device.type, dtype=torch.bfloat16,
                            enabled=self.precision == "bfloat16"):
            outputs = self.network(batch["p0"], batch["p1"], at, rows)
        losses = task_losses(outputs, batch, self.network.config.distance_mode, self.voxel_size)
        return self.weighting(losses), torch.stack(list(losses.values()))


def hits_first(hit: Bool[torch.Tensor, " segments"]) -> Int64[torch.Tensor, " segments"]:
    """The row indices of a batch, its hits first, each part in row order: the stable sort
    of the misses' flags, made by counting (a sort took several times as long), without a
    read on the host."""
    flags = hit.to(torch.int64)
    hits_before = torch.cumsum(flags, 0).sub_(flags)
    index = torch.arange(len(hit), device=hit.device)
    place = torch.where(hit, hits_before, index - hits_before + flags.sum())
    return torch.empty_like(place).scatter_(0, place, index)


def field_rows(hit: Bool[torch.Tensor, " segments"], batch_size: int) -> int:
    """Rows of a batch that cover its hits: a batch of ``batch_size`` rows drawn with
    replacement from rows of which a share p hit holds Binomial(batch_size, p) hits; their
    mean and 6 standard deviations (a batch with more leaves its excess hits out of the
    fields' losses once in about 10^9 batches)."""
    share = float(hit.float().mean()) if hit.numel() else 1.0
    spread = 6.0 * math.sqrt(batch_size * share * (1.0 - share))
    return min(batch_size, math.ceil(batch_size * share + spread) + 1)


def _optimizer(
    objective: Objective, config: TrainConfig
) -> tuple[torch.optim.Adam, torch.optim.lr_scheduler.LambdaLR]:
    """Adam with instant-ngp's settings for the grid table, and an exponential lr decay.

    The fused Adam (one kernel over all of a group's parameters instead of a handful of
    tensor operations per parameter) computes the same update.
    """
    tables = [grid.table for grid in objective.network.modules() if isinstance(grid, HashGrid)]
    weights = list(objective.weighting.parameters())
    mlp = [p for p in objective.network.parameters() if all(p is not t for t in tables)]
    groups = [{"params": tables, "lr": config.lr_grid, "eps": 1e-15},
              {"params": mlp, "lr": config.lr_mlp}]
    if weights:
        groups.append({"params": weights, "lr": config.lr_weighting})
    optimizer = torch.optim.Adam(
        groups,
        betas=(0.9, 0.99),
        fused=True,
    )
    decay = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: config.final_lr_fraction ** (step / config.steps)
    )
    return optimizer, decay


@contextlib.contextmanager
def flushed_denormals() -> Iterator[None]:
    """Within the block, this thread's CPU float arithmetic reads and writes numbers below
    float32's smallest normal (1.2e-38) as zero, and after it no longer (the default). Adam's
    first moments of the weights of ReLU units that stopped firing, and of table rows read
    rarely, decay by 0.9 a step into that range, and arithmetic on it takes the CPU's slow
    path, which slows the steps as training goes on (DESIGN section 8). The updates they
    make are far below a weight's last bit. The encoder's workers take the setting from this
    thread (``threads.flush_denormals``); torch's own threads beyond this one keep the
    default."""
    threads.flush_denormals(True)
    try:
        yield
    finally:
        threads.flush_denormals(False)


class TrainingStep:
    """One optimizer step of ``train``: forward, losses, backward, the finite check, Adam,
    learning-rate decay, and the cancel flag.

    ``model`` is ``objective`` or its DistributedDataParallel wrapper. Calling it with a batch
    returns (cancelled, total loss, task losses); a non-finite loss or gradient raises
    VDNIFError naming the step (1-based, before its update), and no update is applied from
    that step on.

    Reading a value on the host waits for the device to finish everything queued, so the
    flags are read only at check points: the steps that end a progress window (every
    ``log_interval`` steps and the last, where the loop reads its losses and validates
    anyway) and a cancel this process sees alone. Between them the non-finite flag stays on
    the device, sticky, as the fused Adam's ``found_inf`` (the flag ``GradScaler`` hands
    it): Adam skips its update on the device while the flag is 1, so the weights stay those
    before the first bad step. The processes of a ``torchrun`` group agree on the flag at
    every step (a collective the device queues, without a host wait), so that all skip the
    same updates, and on a cancel at the check points, which all of them reach together.
    """

    def __init__(self, objective: Objective, config: TrainConfig, model: nn.Module | None = None,
                 group: ProcessGroup | None = None) -> None:
        self.model = model or objective
        self.group = group or ProcessGroup()
        self.optimizer, self.decay = _optimizer(objective, config)
        self.params = list(objective.parameters())
        self.tasks = list(objective.network.head_sizes)
        self.log_interval, self.steps = config.log_interval, config.steps
        self.calls = 0
        device = self.params[0].device
        # 1 from the first non-finite step on (the fused Adam skips only at exactly 1, in
        # float32), that step's number and its task losses, for the error.
        self.diverged = torch.zeros((), dtype=torch.float32, device=device)
        self.first_bad = torch.zeros((), dtype=torch.int64, device=device)
        self.bad_losses = torch.zeros(len(self.tasks), device=device)
        self.optimizer.found_inf = self.diverged  # read by every step, updated in place

    def __call__(self, batch: Segments, cancel: threading.Event | None = None
                 ) -> tuple[bool, Float[torch.Tensor, ""], Float[torch.Tensor, " tasks"]]:
        total, losses = self.model(batch)
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        grad_norm = torch.nn.utils.get_total_norm(
            [p.grad for p in self.params if p.grad is not None]
        )
        self.calls += 1
        bad = self.group.max((~(torch.isfinite(total) & torch.isfinite(grad_norm))).float())
        first = bad > self.diverged
        self.first_bad.masked_fill_(first, self.calls)
        self.bad_losses.copy_(torch.where(first, losses.detach(), self.bad_losses))
        torch.maximum(self.diverged, bad, out=self.diverged)
        requested = cancel is not None and cancel.is_set()
        if (record_due(self.calls, self.log_interval, self.steps)
                or (requested and not self.group.active)) and self._check(requested):
            return True, total, losses
        self.optimizer.step()
        self.decay.step()
        return False, total, losses

    def _check(self, requested: bool) -> bool:
        """Reads the flags on the host (the one wait for the device): raises for the first
        non-finite step; whether any process asked to cancel (``requested``: this one)."""
        flags = torch.stack([self.diverged, torch.full_like(self.diverged, float(requested))])
        diverged, cancelled = self.group.max(flags).tolist()
        if diverged:
            detail = ", ".join(
                f"{task}={value:.4g}" for task, value in zip(self.tasks, self.bad_losses.tolist())
            )
            raise VDNIFError(
                f"training stopped at step {int(self.first_bad)}: "
                f"the loss or its gradient is not finite ({detail})"
            )
        return bool(cancelled)


def train(
    segments: Sequence[Mapping[str, np.ndarray]],
    header: DatasetHeader,
    config: TrainConfig,
    network_config: NetworkConfig,
    progress: Callable[[dict[str, Any]], None] | None = None,
    cancel: threading.Event | None = None,
    group_timeout_s: float = GROUP_TIMEOUT_S,
) -> TrainResult:
    """Train an ``IntersectionNetwork`` on ``segments`` (``training.data`` states the
    contract of ``segments`` and ``header``).

    The heads follow ``header.heads``, and the hash tables the scene's occupied voxels where
    the header counts them (``network.sized_to_scene``). Every ``log_interval`` steps (and at
    the end) the main process calls ``progress`` with step, steps, mean task losses since the
    last call, total, log-variances, samples/s, ETA seconds and validation metrics on a fixed
    subset of the held-out poses; the stopping rule (``training.stopping``,
    ``config.stop_patience``) may end training there, status "converged". ``cancel`` (e.g. a
    threading.Event): once set, training stops before the next update (under ``torchrun``,
    before the update of the step due to report next, where the processes agree on it) and
    returns the model as it is, status "cancelled". Under ``torchrun`` (WORLD_SIZE > 1) each
    rank trains on ``segments[rank::world]`` with gradients averaged by
    DistributedDataParallel; every rank returns the same weights; a process waits
    ``group_timeout_s`` seconds at most for the others (``distributed.ProcessGroup``).
    """
    if not isinstance(header, DatasetHeader):
        raise VDNIFError("the dataset header must be a training.header.DatasetHeader, got "
                         f"{type(header).__name__}")
    h = header.voxel_size
    heads = header.heads.network_heads()
    network_config = dataclasses.replace(network_config, heads=heads)
    if header.grid.occupied_voxels is not None:
        network_config = sized_to_scene(network_config, header.grid.occupied_voxels,
                                        max(header.grid.dims))
    device = resolve_device(config.device)
    group = ProcessGroup.from_environment(device, group_timeout_s)
    view_from = header.rays_per_pose if header.view_rays else None
    try:
        return _train(segments, h, config, network_config, device, group, progress, cancel,
                      view_from)
    except RuntimeError as exc:
        stalled = group.stalled(exc)
        if stalled is None:
            raise
        raise stalled from None
    finally:
        group.close()


def _train(
    segments: Sequence[Mapping[str, np.ndarray]],
    h: float,
    config: TrainConfig,
    network_config: NetworkConfig,
    device: torch.device,
    group: ProcessGroup,
    progress: Callable[[dict[str, Any]], None] | None,
    cancel: threading.Event | None,
    view_from: int | None = None,
) -> TrainResult:
    """``train`` once the voxel size h, the device and the process group are known; rays
    numbered ``view_from`` and up are the calibration view's (``data.split_data``)."""
    started = time.perf_counter()
    train_data, val_data, view_data, val_poses = split_data(
        segments, config, network_config.heads, device, group, view_from
    )
    timings = {"split_s": time.perf_counter() - started, "validation_s": 0.0,
               "validations": 0, "held_out_rows": _rows(val_data)}
    batches = Batches(train_data, config.batch_size, config.seed + group.rank)
    probe = batches.subset(val_data, config.val_segments)
    timings["probe_rows"] = _rows(probe)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        network = IntersectionNetwork(network_config)
    weighting = make_weighting(config.weighting, list(network.head_sizes),
                               config.weighting_start)
    objective = Objective(network, weighting, h, config.field_jitter, config.seed + group.rank,
                          field_rows(train_data["hit"], config.batch_size),
                          resolve_precision(config.precision, device)).to(device)
    model = (
        nn.parallel.DistributedDataParallel(objective, broadcast_buffers=False)
        if group.active
        else objective
    )
    step_once = TrainingStep(objective, config, model, group)
    log = ProgressLog(step_once.tasks, config.steps, config.log_interval,
                      config.batch_size * group.world, device)

    rule = StoppingRule(config.stop_patience, config.stop_min_gain)
    status = "completed"
    with flushed_denormals():
        for _ in range(config.steps):
            started = time.perf_counter()
            cancelled, total, losses = step_once(batches.next(), cancel)
            if cancelled:
                status = "cancelled"
                break
            log.add(total, losses, time.perf_counter() - started)
            if log.due:
                checked = time.perf_counter()
                validation = validate(network, probe, h, group)
                timings["validation_s"] += time.perf_counter() - checked
                timings["validations"] += 1
                record = log.record(weighting.log_variances(), validation)
                if progress is not None and group.rank == 0:
                    progress(record)
                if rule.update(log.steps_done, validation):
                    status = "converged"
                    break

    started = time.perf_counter()
    network.eval()
    outputs = head_outputs(network, val_data)
    occlusion = calibrate_threshold(head_outputs(network, view_data), view_data, group)
    if occlusion is None:       # a dataset without calibration views: by its segments
        occlusion = calibrate_threshold(outputs, val_data, group, by_ray=False)
    if occlusion is None:
        occlusion = OCCLUSION_THRESHOLD
    network.thresholds = Thresholds(occlusion, calibrate_candidate_threshold(
        outputs, val_data, h, occlusion, network_config.distance_mode, group))
    validation = validate(network, val_data, h, group, outputs)
    timings["final_s"] = time.perf_counter() - started
    return TrainResult(
        network=network,
        network_config=network_config,
        config=config,
        status=status,
        steps=log.steps_done,
        validation=validation,
        log_variances=weighting.log_variances(),
        history=log.history,
        seconds=log.seconds,
        samples_per_s=log.samples_per_s,
        val_poses=val_poses,
        rank=group.rank,
        world_size=group.world,
        timings=timings,
    )


def _rows(data: Segments) -> int:
    """Rows of ``data`` (0 for none)."""
    return int(data["p0"].shape[0]) if data and "p0" in data else 0
