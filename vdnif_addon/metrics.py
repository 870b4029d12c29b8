"""The metrics of DESIGN section 10, comparing two sets of per-ray passes."""

from dataclasses import dataclass

import numpy as np


PSNR_FLOOR_MSE = 1e-10     # identical albedo reports 100 dB instead of infinity (valid JSON)


@dataclass
class Passes:
    """Per-ray (per-pixel) results: what a reference or the network says each ray sees."""

    hit: np.ndarray          # (R,) bool
    distance: np.ndarray     # (R,) float64 along the deformed ray, object-local units
    normal: np.ndarray       # (R, 3) float64 unit, deformed space
    albedo: np.ndarray       # (R, 3) float32
    material: np.ndarray     # (R,) int32

    @classmethod
    def empty(cls, rays):
        return cls(hit=np.zeros(rays, bool), distance=np.zeros(rays),
                   normal=np.zeros((rays, 3)), albedo=np.zeros((rays, 3), np.float32),
                   material=np.zeros(rays, np.int32))

    @classmethod
    def concatenate(cls, passes):
        return cls(*(np.concatenate([getattr(p, name) for p in passes])
                     for name in ("hit", "distance", "normal", "albedo", "material")))


def compare(predicted, reference, object_size, heads=None):
    """Errors of ``predicted`` against ``reference`` over rays where both hit.

    ``distance_mae`` is in object units (divided by ``object_size``, the rest mesh's longest
    side), ``normal_error_deg`` is the mean angle, ``hit_iou`` compares the hit masks;
    ``albedo_psnr`` and ``material_accuracy`` are added where ``heads`` asks for them.
    """
    both = predicted.hit & reference.hit
    union = predicted.hit | reference.hit
    result = {"hit_iou": float(both.sum() / union.sum()) if union.any() else 1.0,
              "compared_rays": int(both.sum())}
    if not both.any():
        result.update(distance_mae=None, normal_error_deg=None)
        return result
    error = np.abs(predicted.distance[both] - reference.distance[both])
    result["distance_mae"] = float(error.mean() / object_size)
    cosine = np.clip((predicted.normal[both] * reference.normal[both]).sum(1), -1.0, 1.0)
    result["normal_error_deg"] = float(np.degrees(np.arccos(cosine)).mean())
    heads = heads or {}
    if heads.get("albedo") or heads.get("albedo_psnr"):
        mse = float(np.mean((np.clip(predicted.albedo[both], 0, 1)
                             - np.clip(reference.albedo[both], 0, 1)) ** 2))
        result["albedo_psnr"] = float(-10 * np.log10(max(mse, PSNR_FLOOR_MSE)))
    if heads.get("material"):
        result["material_accuracy"] = float(
            (predicted.material[both] == reference.material[both]).mean())
    return result
