"""How a network does on held-out segments: task losses and metrics (``evaluate``, summed
over processes by ``validate``) and the calibrated thresholds of DESIGN section 9: the
occlusion threshold that says whether a ray hits (``calibrate_threshold``, on the held-out
calibration views) and the lower candidate threshold that says where
(``calibrate_candidate_threshold``). Each reads the network's outputs on its held-out rows
(``head_outputs``), so that the end of training runs the network over them once."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..model.network import IntersectionNetwork, readout
from ..settings import OCCLUSION_THRESHOLD, Heads
from .distributed import ProcessGroup
from .losses import task_losses

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Float64, Int64

    from .data import Segments

SUMS = (
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
"""The summable quantities of an evaluation, in ``evaluation_sums`` order."""

THRESHOLD_BINS = 50
THRESHOLD_RANGE = (0.1, 0.9)
"""Occlusion thresholds tried: 0.02 apart, so that a probability histogram of THRESHOLD_BINS bins
summed over processes counts the errors of each exactly; only those in THRESHOLD_RANGE."""

CANDIDATE_THRESHOLDS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.4)
"""Candidate thresholds tried below the occlusion threshold (which is tried too). Spread
over decades because the distance error is flat over a decade or two of low thresholds and
rises steeply above them (DESIGN section 8, the candidate threshold)."""


@torch.inference_mode()
def head_outputs(
    network: IntersectionNetwork, data: Segments, batch: int = 2**16
) -> dict[str, Float[torch.Tensor, "segments ..."]]:
    """The network's head outputs over every row of ``data`` (a point field's at the
    reference's hit), its MLPs in its ``precision`` (float32 while it trains), in chunks of
    ``batch`` rows: the one pass over the held-out poses that both calibrations and the final
    validation read (each pass is seconds on a CPU)."""
    chunks = [slice(start, start + batch) for start in range(0, data["p0"].shape[0], batch)]
    # the encoder of a chunk runs beside the MLP of the one before (``encoded``), and the
    # fields, whose grids launch kernels too, once that is done
    pairs = [(data["p0"][rows], data["p1"][rows]) for rows in chunks]
    parts = []
    for features in network.encoded(pairs):
        with network.mlp_arithmetic(features.device):
            parts.append(network.heads(features))
    for part, rows in zip(parts, chunks):
        # the fields only where a loss or figure reads them: at the hits
        network.add_fields(part, data["p0"][rows], data["p1"][rows], data["hit_frac"][rows],
                           data["hit"][rows].nonzero().squeeze(1))
    return {key: torch.cat([part[key] for part in parts]) for key in parts[0]} if parts else {}


@torch.inference_mode()
def evaluation_sums(
    network: IntersectionNetwork, outputs: dict[str, torch.Tensor], data: Segments,
    voxel_size: float, batch: int = 2**16,
) -> Float64[torch.Tensor, " quantities"]:
    """Per-quantity sums (len(SUMS),) float64 over ``data`` (``training.data.Segments``)
    given the network's ``head_outputs`` on it, summable across processes; the network
    gives the distance mode and its thresholds."""
    mode = network.config.distance_mode
    sums = torch.zeros(len(SUMS), dtype=torch.float64, device=data["p0"].device)
    for start in range(0, data["p0"].shape[0], batch):
        part = {key: value[start : start + batch] for key, value in data.items()}
        predicted_outputs = {key: value[start : start + batch] for key, value in outputs.items()}
        losses = task_losses(predicted_outputs, part, mode, voxel_size)
        predicted = readout(predicted_outputs, mode, voxel_size, part["rest_len"],
                            network.thresholds)
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
        sums += torch.stack([terms[name].to(sums) for name in SUMS])
    return sums


def metrics(
    sums: Float64[torch.Tensor, " quantities"], voxel_size: float, heads: Heads
) -> dict[str, float]:
    """Means of ``evaluation_sums`` (len(SUMS),): losses per segment or per hit, accuracies,
    distance MAE (rest units and voxels), normal error in degrees."""
    s = dict(zip(SUMS, sums.tolist()))
    hits = max(s["hits"], 1.0)
    result = {
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
        result["loss/albedo"] = s["albedo_loss"] / hits
    if heads.material:
        result["loss/material"] = s["material_loss"] / hits
        result["material_accuracy"] = s["material_correct"] / hits
    return result


def evaluate(
    network: IntersectionNetwork,
    data: Segments,
    voxel_size: float,
    batch: int = 2**16,
) -> dict[str, float]:
    """Task losses and metrics of ``network`` on ``training.data.load_segments`` tensors.

    Hit-dependent metrics use the true hits: ``distance_mae`` (rest units; also in voxels),
    ``normal_error_deg``, ``material_accuracy``; ``occlusion_accuracy`` uses every segment.
    """
    outputs = head_outputs(network, data, batch)
    return metrics(evaluation_sums(network, outputs, data, voxel_size, batch), voxel_size,
                   network.config.heads)


def validate(
    network: IntersectionNetwork,
    data: Segments,
    voxel_size: float,
    group: ProcessGroup,
    outputs: dict[str, torch.Tensor] | None = None,
) -> dict[str, float] | None:
    """Metrics on held-out data summed over processes (``outputs``: the network's
    ``head_outputs`` on it, computed here without them); None when no process holds any."""
    was_training = network.training
    network.eval()
    if outputs is None:
        outputs = head_outputs(network, data)
    sums = group.sum(evaluation_sums(network, outputs, data, voxel_size))
    network.train(was_training)
    return metrics(sums, voxel_size, network.config.heads) if sums[0] > 0 else None


@torch.inference_mode()
def threshold_errors(
    outputs: dict[str, torch.Tensor],
    data: Segments,
    group: ProcessGroup | None = None,
    by_ray: bool = True,
) -> tuple[list[float], list[float]] | None:
    """(holes, extras): their counts on the rays of ``data`` (with
    ``training.data.RAY_FIELDS``) at each occlusion threshold k / THRESHOLD_BINS, k = 0 ..
    THRESHOLD_BINS, given the network's ``head_outputs`` on them; None without rows to
    count.

    A ray is counted as the render answers it (DESIGN section 9): a hit when any of its
    segments is above the threshold. A hole is a ray that the reference hits and whose
    segments all lie at or below it, an extra a ray that the reference misses and one of
    whose segments lies above it, as the clean rule counts pixels. With ``by_ray`` False
    each segment is counted as a ray of its own."""
    group = group or ProcessGroup()
    device = data["p0"].device
    counts = torch.zeros(2, THRESHOLD_BINS, dtype=torch.float64, device=device)
    if data["p0"].shape[0]:
        probability = torch.sigmoid(outputs["occlusion"].float())
        hit = data["hit"]
        if by_ray:
            ray, rays = _ray_index(data)
            probability = probability.new_zeros(rays).scatter_reduce_(
                0, ray, probability, "amax", include_self=False)
            hit = hit.new_zeros(rays).scatter_reduce_(0, ray, hit, "amax", include_self=False)
        bins = (probability * THRESHOLD_BINS).long().clamp(0, THRESHOLD_BINS - 1)
        counts.index_put_((hit.long(), bins),
                          torch.ones_like(probability, dtype=torch.float64), accumulate=True)
    counts = group.sum(counts)
    if counts.sum() == 0:
        return None
    # Threshold k / BINS: hit rays in bins below k are holes, missed rays in bins k and up
    # extras.
    holes = torch.cat([counts.new_zeros(1), counts[1].cumsum(0)])
    extras = counts[0].sum() - torch.cat([counts.new_zeros(1), counts[0].cumsum(0)])
    return holes.tolist(), extras.tolist()


def calibrate_threshold(
    outputs: dict[str, torch.Tensor],
    data: Segments,
    group: ProcessGroup | None = None,
    by_ray: bool = True,
) -> float | None:
    """The occlusion threshold whose larger count of holes and extras (``threshold_errors``)
    on the rays of ``data`` (the held-out calibration views) is least
    (``settings.OCCLUSION_CALIBRATION``), given the network's
    ``head_outputs`` on them, among the multiples of 1/THRESHOLD_BINS in THRESHOLD_RANGE;
    ties go to the one nearest OCCLUSION_THRESHOLD; None without rows to count.

    The clean rule bounds each of the two, so the larger is what a threshold must keep low;
    their sum is flat over a wide band of thresholds on a camera's rays, and its least fell
    where one of them ran over the rule (DESIGN section 8). With ``by_ray`` False each
    segment is counted as a ray of its own (a dataset without calibration views), and the
    threshold is the one that misclassifies the fewest: a segment is not a camera's pixel,
    and most of a ray's segments miss."""
    errors = threshold_errors(outputs, data, group, by_ray)
    if errors is None:
        return None
    holes, extras = errors
    return least_threshold([max(h, e) if by_ray else h + e for h, e in zip(holes, extras)])


def least_threshold(score: list[float]) -> float:
    """The threshold k / THRESHOLD_BINS in THRESHOLD_RANGE whose ``score[k]`` is least (one
    score per threshold of ``threshold_errors``); ties go to the one nearest
    OCCLUSION_THRESHOLD."""
    low, high = (round(edge * THRESHOLD_BINS) for edge in THRESHOLD_RANGE)
    best = min(range(low, high + 1),
               key=lambda k: (score[k], abs(k / THRESHOLD_BINS - OCCLUSION_THRESHOLD)))
    return best / THRESHOLD_BINS


@torch.inference_mode()
def calibrate_candidate_threshold(
    outputs: dict[str, torch.Tensor],
    data: Segments,
    voxel_size: float,
    occlusion: float,
    distance_mode: str,
    group: ProcessGroup | None = None,
) -> float:
    """The candidate threshold that places hits best on ``data`` (the held-out poses, with
    ``training.data.RAY_FIELDS``; a ray's rows in walk order), given the network's
    ``head_outputs`` on them (of ``distance_mode``): among CANDIDATE_THRESHOLDS
    below the ``occlusion`` threshold and that threshold itself, the one with the least
    mean |D - D_ref| over the rays that the reference and the network both hit, D the
    deformed distance ``t0 + fraction * seg_len`` on the ray's first segment above it, D_ref
    on its first hit segment. Ties go to the higher one; without such rays (or held-out
    segments) it is the occlusion threshold, which places hits where it finds them."""
    group = group or ProcessGroup()
    thresholds = [t for t in CANDIDATE_THRESHOLDS if t < occlusion] + [occlusion]
    device = data["p0"].device
    sums = torch.zeros(len(thresholds) + 1, dtype=torch.float64, device=device)
    if data["p0"].shape[0]:
        predicted = readout(outputs, distance_mode, voxel_size, data["rest_len"])
        probability = predicted["hit_probability"].float()
        distance = data["t0"].double() + predicted["fraction"].double() * data["seg_len"].double()
        ray, rays = _ray_index(data)
        reference = _first_per_ray(data["hit"], data["t0"].double() + data["hit_frac"].double()
                                   * data["seg_len"].double(), ray, rays)
        # Every threshold tried reads only rows above the lowest one, in their order, so
        # their first is a ray's first: they are taken once.
        above = probability > thresholds[0]
        probability, distance, ray = probability[above], distance[above], ray[above]
        confident = _first_per_ray(probability > occlusion, distance, ray, rays)
        both = ~(reference.isnan() | confident.isnan())
        for index, threshold in enumerate(thresholds):
            placed = _first_per_ray(probability > threshold, distance, ray, rays)
            sums[index] = (placed[both] - reference[both]).abs().sum()
        sums[-1] = both.sum()
    sums = group.sum(sums)
    if sums[-1] == 0:
        return occlusion
    errors = sums[:-1].tolist()
    return thresholds[min(range(len(thresholds)), key=lambda k: (errors[k], -k))]


def _ray_index(data: Segments) -> tuple[Int64[torch.Tensor, " S"], int]:
    """Each row's ray of ``data`` as an index 0..rays-1 (a ray is a pose's ray number), and
    the number of rays."""
    _, ray = torch.unique(data["pose"] * (int(data["ray"].max()) + 1) + data["ray"],
                          return_inverse=True)
    return ray, int(ray.max()) + 1


def _first_per_ray(mask: Bool[torch.Tensor, " S"], value: Float64[torch.Tensor, " S"],
                   ray: Int64[torch.Tensor, " S"], rays: int) -> Float64[torch.Tensor, " rays"]:
    """(rays,) ``value`` of each ray's first row (in row order) where ``mask`` holds, NaN
    where none does."""
    row = torch.arange(len(mask), device=mask.device)
    first = torch.full((rays,), len(mask), dtype=torch.int64, device=mask.device)
    first.scatter_reduce_(0, ray[mask], row[mask], "amin")
    out = torch.full((rays,), float("nan"), dtype=torch.float64, device=mask.device)
    found = first < len(mask)
    out[found] = value[first[found]]
    return out
