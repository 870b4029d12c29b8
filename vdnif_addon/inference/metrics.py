"""The metrics of DESIGN section 10, comparing two sets of per-ray passes."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import VDNIFError
from ..passes import Passes, SecondaryPasses
from ..text import percent

if TYPE_CHECKING:
    from jaxtyping import Bool


PSNR_FLOOR_MSE = 1e-10     # identical albedo reports 100 dB instead of infinity (valid JSON)
# A model whose hit mask overlaps the true reference's by less than this (hit IoU) does not
# predict hits: its rays stop in other cells than a working model's, so its rays/s measure
# another workload and are no speed figure (DESIGN section 10).
SPEED_MIN_HIT_IOU = 0.9
CLEAN_RATE = 0.005
"""An evaluation's verdict is "clean" when its false-negative (holes) and false-positive
(extras) rates against the true reference are each at most this share of the reference's
hits, else "speckled" (``verdict``). A judgement, inside the range of the converged models
of the bench sweep (0.05 % to 0.8 % each, docs/performance.md)."""


def _share(count: int, total: int) -> float | None:
    return float(count / total) if total else None


def compare(predicted: Passes, reference: Passes, object_size: float,
            heads: dict[str, Any] | None = None, voxel_size: float | None = None,
            pixels: Bool[np.ndarray, " R"] | None = None) -> dict[str, float | int | None]:
    """Errors of ``predicted`` against ``reference``.

    Hit-mask metrics count every ray: ``hit_iou`` (None when neither hits anything),
    ``false_negative_rate`` (reference hits the prediction misses) and
    ``false_positive_rate`` (prediction hits the reference misses), both over the
    reference's hits (None without any). The other metrics are taken over the rays where
    both hit, restricted to ``pixels`` (R,) bool when given (the common pixel set of
    compared models, see ``common_pixels``): ``distance_mae`` in object units (divided by
    ``object_size``, the rest mesh's longest side), ``distance_mae_voxels`` (divided by
    ``voxel_size``; only when it is given), ``normal_error_deg`` the mean angle;
    ``albedo_psnr`` and ``material_accuracy`` where ``heads`` asks for them.
    ``compared_rays`` counts the rays they are taken over.
    """
    reference_hits = int(reference.hit.sum())
    union = predicted.hit | reference.hit
    both = predicted.hit & reference.hit
    result = {
        "hit_iou": _share(both.sum(), union.sum()),
        "false_negative_rate": _share((reference.hit & ~predicted.hit).sum(), reference_hits),
        "false_positive_rate": _share((predicted.hit & ~reference.hit).sum(), reference_hits),
    }
    if pixels is not None:
        both = both & pixels
    result["compared_rays"] = int(both.sum())
    heads = heads or {}
    albedo = bool(heads.get("albedo") or heads.get("albedo_psnr"))
    material = bool(heads.get("material"))
    if not both.any():
        result.update(distance_mae=None, normal_error_deg=None)
        result.update({} if voxel_size is None else {"distance_mae_voxels": None})
        result.update({"albedo_psnr": None} if albedo else {})
        result.update({"material_accuracy": None} if material else {})
        return result
    error = np.abs(predicted.distance[both] - reference.distance[both]).mean()
    result["distance_mae"] = float(error / object_size)
    if voxel_size is not None:
        result["distance_mae_voxels"] = float(error / voxel_size)
    cosine = np.clip((predicted.normal[both] * reference.normal[both]).sum(1), -1.0, 1.0)
    result["normal_error_deg"] = float(np.degrees(np.arccos(cosine)).mean())
    if albedo:
        mse = float(np.mean((np.clip(predicted.albedo[both], 0, 1)
                             - np.clip(reference.albedo[both], 0, 1)) ** 2))
        result["albedo_psnr"] = float(-10 * np.log10(max(mse, PSNR_FLOOR_MSE)))
    if material:
        result["material_accuracy"] = float(
            (predicted.material[both] == reference.material[both]).mean())
    return result


def compare_secondary(predicted: SecondaryPasses, reference: SecondaryPasses,
                      pixels: Bool[np.ndarray, " R"] | None = None, suffix: str = ""
                      ) -> dict[str, float | int | None]:
    """Errors of the secondary passes ``predicted`` against ``reference`` over the rays where
    both start from a primary hit (and ``pixels`` (R,) when given): ``ao_mae``, the mean
    absolute AO difference (0..1); ``shadow_false_lit_rate``, rays the prediction lights
    over those the reference shadows; ``shadow_false_shadow_rate``, rays it shadows over
    those the reference lights (None without any); the part of each that a normal facing
    away from the light decides, with no shadow ray cast (the reference's for false lit,
    the prediction's for false shadow): ``shadow_false_lit_facing_rate`` and
    ``shadow_false_shadow_facing_rate``, over the same rays (the rest are cast shadows);
    ``secondary_rays``, how many; every key ends in ``suffix``."""
    both = predicted.hit & reference.hit
    if pixels is not None:
        both = both & pixels
    lit, shadowed = both & reference.lit, both & ~reference.lit
    result = {
        "secondary_rays": int(both.sum()),
        "ao_mae": (float(np.abs(predicted.ao[both] - reference.ao[both]).mean())
                   if both.any() else None),
        "shadow_false_lit_rate": _share((shadowed & predicted.lit).sum(), shadowed.sum()),
        "shadow_false_shadow_rate": _share((lit & ~predicted.lit).sum(), lit.sum()),
        "shadow_false_lit_facing_rate": _share(
            (shadowed & predicted.lit & ~reference.facing).sum(), shadowed.sum()),
        "shadow_false_shadow_facing_rate": _share(
            (lit & ~predicted.lit & ~predicted.facing).sum(), lit.sum()),
    }
    return {f"{key}{suffix}": value for key, value in result.items()}


def common_pixels(pairs: Iterable[tuple[Passes, Passes]]) -> Bool[np.ndarray, " R"]:
    """(R,) bool: the rays where every (predicted, reference) Passes pair of ``pairs`` hits
    on both sides, the common pixel set over which compared models' errors are taken
    (DESIGN section 10). All pairs must be over the same rays."""
    pairs = list(pairs)
    sizes = {len(p.hit) for pair in pairs for p in pair}
    if len(sizes) != 1:
        raise ValueError(f"compared passes cover different numbers of rays: {sorted(sizes)}")
    common = np.ones(sizes.pop(), bool)
    for predicted, reference in pairs:
        common &= predicted.hit & reference.hit
    return common


def speed_withheld(hit_iou: float | None) -> str | None:
    """Why no speed figure may be given for a trained model whose hit IoU against the true
    reference is ``hit_iou``, or None when it may: only models that predict hits (hit IoU
    at least SPEED_MIN_HIT_IOU) have speeds (DESIGN section 10). The one place that decides
    it for every report, table and preset."""
    if hit_iou is None:
        return "neither the model nor the true reference hits anything"
    if hit_iou < SPEED_MIN_HIT_IOU:
        return (f"hit IoU {hit_iou:.3f} against the true reference is below "
                f"{SPEED_MIN_HIT_IOU}: the model does not predict hits")
    return None


def verdict(metrics: dict[str, Any]) -> str:
    """One line on an evaluation's hit mask against the true reference (its ``vs_true``
    metrics): "clean" when holes and extras are each at most CLEAN_RATE of the reference's
    hits, else "speckled" with both shares."""
    holes, extras = metrics.get("false_negative_rate"), metrics.get("false_positive_rate")
    if holes is None or extras is None:
        return "n/a (the true reference hits nothing)"
    if holes <= CLEAN_RATE and extras <= CLEAN_RATE:
        return "clean"
    return f"speckled: {percent(holes, 2)} holes, {percent(extras, 2)} extras"


def check_compared(metrics: dict[str, Any], name: str) -> None:
    """Raises VDNIFError when ``metrics`` (``compare`` over every view of an evaluation of
    ``name``) had nothing to compare: the true reference hits nothing in any view, so every
    figure is "n/a" and the views missed the object. (A prediction that hits none of the
    reference's pixels is a result: hit IoU 0, every hit a false negative.)"""
    if metrics.get("compared_rays") or metrics.get("false_negative_rate") is not None:
        return
    raise VDNIFError(f"the evaluation of '{name}' compared 0 rays: the true reference hits "
                     "nothing in any view (is the object in view, and not a speck of its own "
                     "bounds?)")
