"""Evaluation of a trained model on a scene (DESIGN section 10), free of Blender: does the
model fit the captured scene, the metrics against both references, and the figures."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import VDNIFError
from ..passes import SHADED_PASS, Passes, SecondaryPasses
from .images import (
    PASSES,
    comparison_figure,
    display,
    error_images,
    secondary_errors,
    secondary_images,
    shaded_display,
    shaded_error,
)
from .metrics import common_pixels, compare, compare_secondary, speed_withheld
from .shading import compare_shaded, in_band, shadow_split

if TYPE_CHECKING:
    from jaxtyping import Bool, Float

    from ..geometry.restmesh import RestMesh
    from ..geometry.voxels import VoxelGrid
    from ..model.metadata import ModelMetadata

    Metrics = dict[str, float | int | None]
    """What ``metrics.compare`` returns."""

REFERENCES = ("true", "embedded")
# What the neural render's timings say of the model's speed: no figure unless it predicts
# hits (metrics.speed_withheld).
RENDER_SPEEDS = ("render_rays_per_s", "render_segments_per_s", "network_fraction")


def check_model_fits(path: str | os.PathLike, metadata: ModelMetadata, mesh: RestMesh,
                     grid: VoxelGrid) -> None:
    """Raises a one-line VDNIFError unless the model in ``path`` (its ``metadata``) was
    trained on this rest ``mesh`` voxelized as ``grid``: same object, resolution, grid,
    mesh and materials. Rendering with another object's network would give garbage."""
    model_grid = metadata.grid
    trained_on = (f"'{metadata.object}' at resolution {model_grid.resolution} "
                  f"(grid {'x'.join(map(str, model_grid.dims))})")
    here = (f"'{mesh.name}' at resolution {grid.resolution} "
            f"(grid {'x'.join(map(str, grid.dims.tolist()))})")
    if metadata.object != mesh.name or model_grid.resolution != grid.resolution:
        raise VDNIFError(f"model '{path}' was trained on {trained_on}, not on {here}: "
                         f"train a model for this object and resolution")
    same_grid = (list(model_grid.dims) == grid.dims.tolist()
                 and np.allclose(model_grid.origin, grid.origin, rtol=1e-6,
                                 atol=1e-9 * mesh.size)
                 and np.isclose(model_grid.voxel_size, grid.voxel_size, rtol=1e-6))
    if not same_grid:
        ratio = grid.voxel_size / model_grid.voxel_size
        if (list(model_grid.dims) == grid.dims.tolist() and not np.isclose(ratio, 1.0)
                and np.allclose(grid.origin, np.asarray(model_grid.origin) * ratio,
                                rtol=1e-5, atol=1e-9 * mesh.size)):
            # the same grid scaled about the object's origin: --scale or the object's scale
            raise VDNIFError(
                f"model '{path}' was trained on '{metadata.object}' at "
                f"{model_grid.voxel_size:.6g} units a voxel, '{mesh.name}' is now {ratio:.4g} "
                f"times that size ({grid.voxel_size:.6g} units a voxel: another --scale or a "
                "scaled object): train a model at this size")

        def described(dims, voxel_size, origin):
            corner = ", ".join(f"{value:.6g}" for value in origin)
            return f"grid {'x'.join(map(str, dims))} of {voxel_size:.6g} at ({corner})"

        raise VDNIFError(
            f"model '{path}' was trained on '{metadata.object}' with the "
            f"{described(model_grid.dims, model_grid.voxel_size, model_grid.origin)}, but "
            f"the mesh of '{mesh.name}' has changed since (now the "
            f"{described(grid.dims.tolist(), grid.voxel_size, grid.origin.tolist())}): "
            "train it again")
    from ..model.model_file import mesh_fingerprint, texture_fingerprint

    known = model_grid.mesh_fingerprint
    if known is not None and known != mesh_fingerprint(mesh):
        raise VDNIFError(f"model '{path}' was trained on another version of the mesh of "
                         f"'{mesh.name}' (its vertices, faces or materials were edited "
                         "since): train it again")
    textures = model_grid.texture_fingerprint             # None: a model older than it
    if textures is not None and textures != texture_fingerprint(mesh):
        images = ", ".join(f"'{a.source}'" for a in mesh.albedo if a.kind == "texture")
        raise VDNIFError(f"model '{path}' was trained on other textures of '{mesh.name}' "
                         f"(now {'the images ' + images if images else 'no image texture'} "
                         "in its materials): train it again")
    materials = metadata.network_config.heads.material_count
    if materials != mesh.material_count:
        raise VDNIFError(f"model '{path}' knows {materials} materials, '{mesh.name}' has "
                         f"{mesh.material_count}: train it again")
    if list(metadata.material_slots) != mesh.material_slots.tolist():
        raise VDNIFError(f"model '{path}' knows the materials of slots "
                         f"{list(metadata.material_slots)}, '{mesh.name}' uses slots "
                         f"{mesh.material_slots.tolist()}: train it again")


def metric_heads(mesh: RestMesh) -> dict[str, bool]:
    """Which optional metrics a scene has (DESIGN section 10): albedo PSNR unless one
    material of constant albedo makes it exact by construction (nothing is predicted),
    material accuracy with several materials."""
    several = mesh.material_count > 1
    return {"albedo_psnr": several or mesh.albedo_varies, "material": several}


def compare_both(predicted: Passes, true: Passes, embedded: Passes, mesh: RestMesh,
                 voxel_size: float | None = None,
                 pixels: dict[str, Bool[np.ndarray, " R"]] | None = None
                 ) -> dict[str, Metrics]:
    """{"vs_true": ..., "vs_embedded": ...}: ``compare`` against each reference, distance
    errors also in voxels of ``voxel_size``; continuous metrics over ``pixels``
    ({"vs_true": (R,) bool, "vs_embedded": ...}, the common pixel sets) when given."""
    heads = metric_heads(mesh)
    pixels = pixels or {}
    return {f"vs_{name}": compare(predicted, reference, mesh.size, heads, voxel_size,
                                  pixels.get(f"vs_{name}"))
            for name, reference in zip(REFERENCES, (true, embedded))}


def compare_secondary_both(views: dict[str, SecondaryPasses],
                           pixels: dict[str, Bool[np.ndarray, " R"]] | None = None
                           ) -> dict[str, Metrics]:
    """{"vs_true": ..., "vs_embedded": ...}: the secondary passes of ``views``
    (``secondary.secondary_views``) compared, the network's from its own hits against each
    reference's from its own, and (keys ending ``_true_hit``) the network's from the true
    hits against the reference's from the same hits: the secondary rays' own error."""
    pixels = pixels or {}
    result = {}
    for name in REFERENCES:
        own = "embedded_true_hit" if name == "embedded" else "true"
        result[f"vs_{name}"] = {
            **compare_secondary(views["predicted"], views[name], pixels.get(f"vs_{name}")),
            **compare_secondary(views["predicted_true_hit"], views[own],
                                suffix="_true_hit")}
    return result


def compare_shaded_both(shaded: dict[str, Float[np.ndarray, "R 3"]],
                        secondary: dict[str, SecondaryPasses],
                        cosines: dict[str, Float[np.ndarray, " R"]], band: float
                        ) -> dict[str, Metrics]:
    """{"vs_true": ..., "vs_embedded": ...}: the shaded prediction against each reference
    shaded alike (``shading.compare_shaded`` over every pixel: a hole shows the world where
    the reference shows the surface), and the shadow rates from the network's own hits
    split at the reference's terminator band |N.L| < ``band`` (``shading.shadow_split``);
    ``shaded``, ``secondary`` and ``cosines`` (``shading.light_cosines``): {"predicted",
    "true", "embedded": ...} of the same rays."""
    return {f"vs_{name}": {**compare_shaded(shaded["predicted"], shaded[name]),
                           **shadow_split(secondary["predicted"], secondary[name],
                                          in_band(cosines[name], band))}
            for name in REFERENCES}


def compare_common(runs: Sequence[dict[str, Passes]], mesh: RestMesh,
                   voxel_sizes: Sequence[float]) -> list[dict[str, Metrics]]:
    """Compared models on one common pixel set per reference (DESIGN section 10).

    ``runs``: per model its joined {"predicted", "true", "embedded"} Passes over the same
    rays (``concatenated``); ``voxel_sizes``: per model the voxel size of its grid. Returns
    per model ``compare_both`` whose distance, normal, albedo and material figures are
    taken over the rays where every model and its reference hit; hit IoU and the rates
    still count every ray.
    """
    truths = [run["true"] for run in runs]
    if any(len(t.hit) != len(truths[0].hit) or not np.array_equal(t.hit, truths[0].hit)
           for t in truths):
        raise VDNIFError("compared models were evaluated on different rays or poses: "
                         "their errors cannot share a pixel set")
    pixels = {f"vs_{name}": common_pixels((run["predicted"], run[name]) for run in runs)
              for name in REFERENCES}
    return [compare_both(run["predicted"], run["true"], run["embedded"], mesh, h, pixels)
            for run, h in zip(runs, voxel_sizes)]


def speed_figures(timings: dict[str, Any], vs_true: Metrics
                  ) -> tuple[dict[str, Any], str | None]:
    """(timings, reason): the neural render's speed figures of ``timings`` kept only for a
    model that predicts hits (metrics.speed_withheld on its hit IoU ``vs_true``), else
    None with the reason why (None when they are kept)."""
    reason = speed_withheld(vs_true["hit_iou"])
    if reason is None:
        return dict(timings), None
    return {key: (None if key in RENDER_SPEEDS else value)
            for key, value in timings.items()}, reason


def concatenated(views: Sequence[dict[str, Passes]]) -> dict[str, Passes]:
    """Passes of every view joined: {"predicted", "true", "embedded"} -> Passes."""
    return {name: Passes.concatenate([view[name] for view in views])
            for name in ("predicted", *REFERENCES)}


def distance_range(*passes: Passes) -> tuple[float, float]:
    """(near, far) over the hit distances of every Passes given: one brightness scale for
    images that are compared; (0, 1) without any hit."""
    hits = np.concatenate([p.distance[p.hit] for p in passes])
    return (hits.min(), hits.max()) if len(hits) else (0.0, 1.0)


class DistanceScale:
    """One brightness scale for the distance previews of a view's prediction and references
    and of every frame of a sequence, so that they compare and a sequence does not flicker:
    the hit distances of the first images given one, widened by a tenth of their span each
    side (an object moving a little nearer or farther stays on it; beyond, the preview
    clips). Images without a hit leave it unset."""

    def __init__(self) -> None:
        self.near_far = None

    def __call__(self, *passes):
        """(near, far): the kept scale, set from ``passes`` (Passes in the images' units)
        when unset."""
        if self.near_far is not None:
            return self.near_far
        near, far = distance_range(*passes)
        if not any(p.hit.any() for p in passes):
            return (near, far)
        pad = 0.1 * (far - near)
        self.near_far = (float(near - pad), float(far + pad))
        return self.near_far


def view_images(reference: Passes, predicted: Passes, height: int, width: int,
                object_size: float) -> dict[str, dict[str, Float[np.ndarray, "H W 3"]]]:
    """{"reference" | "predicted" | "error": {pass: (H, W, 3) image}} of one view: both
    passes on one distance scale, the errors of the prediction as heat maps."""
    near_far = distance_range(reference, predicted)
    return {"reference": display(reference, height, width, near_far),
            "predicted": display(predicted, height, width, near_far),
            "error": error_images(predicted, reference, height, width, object_size)}


def secondary_view_images(reference: SecondaryPasses, predicted: SecondaryPasses, height: int,
                          width: int, shaded: dict[str, Float[np.ndarray, "R 3"]] | None = None
                          ) -> dict[str, dict[str, Float[np.ndarray, "H W 3"]]]:
    """{"reference" | "predicted" | "error": {"ao" | "shadow": (H, W, 3) image}} of one
    view's secondary passes: grey levels and the prediction's errors as heat maps; with
    ``shaded`` ({"true", "predicted": (R, 3)}) its "shaded" images too, as the user sees
    them, the error in visible 8-bit steps (``images.shaded_error``)."""
    shown = {"reference": secondary_images(reference, height, width)["display"],
             "predicted": secondary_images(predicted, height, width)["display"],
             "error": secondary_errors(predicted, reference, height, width)}
    if shaded is not None:
        shown["reference"][SHADED_PASS] = shaded_display(shaded["true"], height, width)
        shown["predicted"][SHADED_PASS] = shaded_display(shaded["predicted"], height, width)
        shown["error"][SHADED_PASS] = shaded_error(shaded["predicted"], shaded["true"], height,
                                                   width)
    return shown


def figure(reference: Passes, predicted: Passes, height: int, width: int, object_size: float
           ) -> Float[np.ndarray, "FH FW 3"]:
    """The reference | predicted | error figure (FH, FW, 3), one row per pass (normal, albedo,
    distance, material)."""
    shown = view_images(reference, predicted, height, width, object_size)
    return comparison_figure([[shown[source][name] for source in ("reference", "predicted",
                                                                  "error")]
                              for name in PASSES])


def world_distances(passes: Passes, scale: Float[np.ndarray, " R"]) -> Passes:
    """A copy of ``passes`` with distances along world rays (local distance / ``scale``,
    the per-ray length of the world-to-local map of the direction)."""
    return Passes(hit=passes.hit, distance=np.where(scale > 0, passes.distance / np.where(
        scale > 0, scale, 1.0), np.inf), normal=passes.normal, albedo=passes.albedo,
        material=passes.material)

