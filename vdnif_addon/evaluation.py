"""Evaluation of a trained model on a scene (DESIGN section 10), free of Blender: does the
model fit the captured scene, the metrics against both references, and the figures."""

import numpy as np

from .errors import VDNIFError
from .images import PASSES, comparison_figure, display, error_images
from .metrics import Passes, compare


def check_model_fits(path, extra, mesh, grid):
    """Raises a one-line VDNIFError unless the model in ``path`` (its metadata ``extra``)
    was trained on this rest ``mesh`` voxelized as ``grid``: same object, resolution, grid
    and materials. Rendering with another object's network would give garbage."""
    model_grid = extra.get("grid") or {}
    trained_on = (f"'{extra.get('object')}' at resolution {model_grid.get('resolution')} "
                  f"(grid {'x'.join(map(str, model_grid.get('dims', [])))})")
    here = (f"'{mesh.name}' at resolution {grid.resolution} "
            f"(grid {'x'.join(map(str, grid.dims.tolist()))})")
    if extra.get("object") != mesh.name or model_grid.get("resolution") != grid.resolution:
        raise VDNIFError(f"model '{path}' was trained on {trained_on}, not on {here}: "
                         f"train a model for this object and resolution")
    same_grid = (list(model_grid.get("dims", [])) == grid.dims.tolist()
                 and np.allclose(model_grid.get("origin"), grid.origin, rtol=1e-6,
                                 atol=1e-9 * mesh.size)
                 and np.isclose(model_grid.get("voxel_size"), grid.voxel_size, rtol=1e-6))
    if not same_grid:
        raise VDNIFError(f"model '{path}' was trained on {trained_on}, but the mesh of "
                         f"'{mesh.name}' has changed since (now {here}): train it again")
    materials = (extra.get("heads") or {}).get("material_count")
    if materials != mesh.material_count:
        raise VDNIFError(f"model '{path}' knows {materials} materials, '{mesh.name}' has "
                         f"{mesh.material_count}: train it again")


def metric_heads(mesh):
    """Which optional metrics a scene has: albedo PSNR always, material accuracy with
    several materials."""
    return {"albedo_psnr": True, "material": mesh.material_count > 1}


def compare_both(predicted, true, embedded, mesh):
    """{"vs_true": ..., "vs_embedded": ...}: ``compare`` against each reference."""
    heads = metric_heads(mesh)
    return {"vs_true": compare(predicted, true, mesh.size, heads),
            "vs_embedded": compare(predicted, embedded, mesh.size, heads)}


def concatenated(views):
    """Passes of every view joined: {"predicted", "true", "embedded"} -> Passes."""
    return {name: Passes.concatenate([view[name] for view in views])
            for name in ("predicted", "true", "embedded")}


def distance_range(*passes):
    """(near, far) over the hit distances of every Passes given: one brightness scale for
    images that are compared; (0, 1) without any hit."""
    hits = np.concatenate([p.distance[p.hit] for p in passes])
    return (hits.min(), hits.max()) if len(hits) else (0.0, 1.0)


def view_images(reference, predicted, height, width, object_size):
    """{"reference" | "predicted" | "error": {pass: (H, W, 3) image}} of one view: both
    passes on one distance scale, the errors of the prediction as heat maps."""
    near_far = distance_range(reference, predicted)
    return {"reference": display(reference, height, width, near_far),
            "predicted": display(predicted, height, width, near_far),
            "error": error_images(predicted, reference, height, width, object_size)}


def figure(reference, predicted, height, width, object_size):
    """The reference | predicted | error figure, one row per pass (normal, albedo,
    distance, material)."""
    shown = view_images(reference, predicted, height, width, object_size)
    return comparison_figure([[shown[source][name] for source in ("reference", "predicted",
                                                                  "error")]
                              for name in PASSES])


def world_distances(passes, scale):
    """A copy of ``passes`` with distances along world rays (local distance / ``scale``,
    the per-ray length of the world-to-local map of the direction)."""
    return Passes(hit=passes.hit, distance=np.where(scale > 0, passes.distance / np.where(
        scale > 0, scale, 1.0), np.inf), normal=passes.normal, albedo=passes.albedo,
        material=passes.material)

