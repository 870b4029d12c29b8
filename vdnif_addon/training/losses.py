"""Per-task losses and their weighting into one training objective (DESIGN.md section 8)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from ..checks import check_choice
from ..errors import VDNIFError
from ..settings import DEFAULT_WEIGHTING_START, WEIGHTING_STARTS, WEIGHTINGS

CLASSIFICATION_TASKS = frozenset({"occlusion", "material"})
"""Tasks weighted as classification, exp(-s) L + s/2; the others are regression tasks."""


def distance_error(
    distance: torch.Tensor, hit_frac: torch.Tensor, distance_mode: str,
    rest_len: torch.Tensor | None = None, voxel_size: float | None = None,
) -> torch.Tensor:
    """Squared error (N,) of the distance head's output ``distance`` (N,) against the hit:
    t/l (``fraction``), expm1 of the ReLU log1p(t/l) output against t/l
    (``log1p-fraction``), or the ReLU output against log1p(d/h) in log space
    (``log-distance``, which alone needs ``rest_len`` and ``voxel_size``).

    hit_frac: (N,), t/l, the hit's fraction of the segment: the error is scale-invariant.
    rest_len: (N,) rest segment lengths; voxel_size: h, in the same rest units.
    """
    if distance_mode == "fraction":
        return (distance - hit_frac).square()
    if distance_mode == "log-distance":
        if rest_len is None or voxel_size is None:
            raise VDNIFError("the log-distance loss needs the rest lengths and the voxel size")
        return (distance - torch.log1p(hit_frac * rest_len / voxel_size)).square()
    # The head outputs log1p(t/l); its error is taken in t/l, the unit the hit is placed
    # in. In log space an error at t/l near 1 weighs (1 / (1 + t/l))^2, a quarter of one
    # near 0, which left far hits worse placed than the sigmoid's (DESIGN section 8). The
    # clamp keeps expm1 finite on the misses' untrained outputs (a NaN gradient through
    # torch.where otherwise); targets stay below log 2.
    return (torch.expm1(distance.clamp(max=4.0)) - hit_frac).square()


def task_losses(
    outputs: Mapping[str, torch.Tensor],
    batch: Mapping[str, torch.Tensor],
    distance_mode: str,
    voxel_size: float | None = None,
) -> dict[str, torch.Tensor]:
    """Scalar loss per head present in ``outputs``; ``voxel_size`` (h, rest units) only for
    the ``log-distance`` mode.

    batch: ``hit`` (N,) bool, ``hit_frac`` (N,), ``rest_len`` (N,), ``normal`` (N, 3),
    ``albedo`` (N, 3), ``material`` (N,) int64. Occlusion (BCE with logits) averages over all
    segments; distance (MSE), normal (1 - cos), albedo (L1) and material (cross-entropy)
    average over hits only, and are exactly 0 (with zero gradient) for a batch without hits.
    """
    hit = batch["hit"]
    hits = hit.sum().clamp_min(1)

    def over_hits(per_segment: torch.Tensor) -> torch.Tensor:
        return torch.where(hit, per_segment, 0.0).sum() / hits

    losses = {
        "occlusion": F.binary_cross_entropy_with_logits(
            outputs["occlusion"], hit.to(outputs["occlusion"].dtype)
        ),
        "distance": over_hits(distance_error(outputs["distance"], batch["hit_frac"],
                                             distance_mode, batch["rest_len"], voxel_size)),
        "normal": over_hits(1.0 - F.cosine_similarity(outputs["normal"], batch["normal"], dim=1)),
    }
    if "albedo" in outputs:
        losses["albedo"] = over_hits((outputs["albedo"] - batch["albedo"]).abs().mean(1))
    if "material" in outputs:
        material = torch.where(hit, batch["material"], 0)
        losses["material"] = over_hits(
            F.cross_entropy(outputs["material"], material, reduction="none")
        )
    return losses


class UncertaintyWeighting(nn.Module):
    """Kendall et al. (2018) multi-task weighting with learned log-variances s_i = log sigma_i^2.

    Total = sum over tasks of ``0.5 exp(-s) L + 0.5 s`` (regression) or ``exp(-s) L + 0.5 s``
    (classification); it may be negative. s starts at 0 (``start="zero"``) or at the log of
    the task's scale, so that every task starts at weight 1 (``"equal"``,
    ``settings.WEIGHTING_STARTS``), and is bounded softly,
    ``s = bound * tanh(raw / bound)``: unlike a hard clamp, whose gradient vanishes once s
    reaches the bound (leaving it stuck there), this keeps s in (-bound, bound) and trainable.
    """

    def __init__(self, tasks: Sequence[str], bound: float = 6.0,
                 start: str = DEFAULT_WEIGHTING_START) -> None:
        super().__init__()
        check_choice("weighting start", start, WEIGHTING_STARTS)
        self.tasks = tuple(tasks)
        self.bound = bound
        scale = torch.tensor([1.0 if task in CLASSIFICATION_TASKS else 0.5
                              for task in self.tasks])
        s = torch.log(scale) if start == "equal" else torch.zeros(len(self.tasks))
        self.raw = nn.Parameter(bound * torch.atanh(s / bound))
        self.register_buffer("_scale", scale, persistent=False)

    def log_variance_tensor(self) -> torch.Tensor:
        """s per task, (K,), in ``tasks`` order."""
        return self.bound * torch.tanh(self.raw / self.bound)

    def forward(self, losses: Mapping[str, torch.Tensor]) -> torch.Tensor:
        s = self.log_variance_tensor()
        stacked = torch.stack([losses[task] for task in self.tasks])
        return (self._scale * torch.exp(-s) * stacked + 0.5 * s).sum()

    def log_variances(self) -> dict[str, float]:
        """Task -> s, for logging."""
        return dict(zip(self.tasks, self.log_variance_tensor().tolist()))


class FixedWeighting(nn.Module):
    """The baselines' objective: the plain sum of the task losses (all weights 1). It learns
    no weights, so every ``start`` (checked, as for ``UncertaintyWeighting``) is the same."""

    def __init__(self, tasks: Sequence[str], start: str = DEFAULT_WEIGHTING_START) -> None:
        super().__init__()
        check_choice("weighting start", start, WEIGHTING_STARTS)
        self.tasks = tuple(tasks)

    def forward(self, losses: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return torch.stack([losses[task] for task in self.tasks]).sum()

    def log_variances(self) -> dict[str, float]:
        return {}


WEIGHTING_CLASSES = dict(zip(WEIGHTINGS, (UncertaintyWeighting, FixedWeighting), strict=True))
"""``settings.WEIGHTINGS`` name -> its module, in that tuple's order."""


def make_weighting(kind: str, tasks: Sequence[str], start: str = DEFAULT_WEIGHTING_START
                   ) -> UncertaintyWeighting | FixedWeighting:
    """``kind`` (one of ``settings.WEIGHTINGS``) over ``tasks``; the uncertainty weighting's
    log-variances start at ``start`` (one of ``settings.WEIGHTING_STARTS``)."""
    check_choice("weighting", kind, WEIGHTINGS)
    return WEIGHTING_CLASSES[kind](tasks, start=start)
