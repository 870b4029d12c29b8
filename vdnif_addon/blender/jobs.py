"""The pipeline's steps as the batch commands and the experiments chain them: datasets for a
variant, training, evaluation on unseen poses, and the images they write."""

import dataclasses
import pathlib

import numpy as np

from ..inference import images
from ..inference.evaluation import distance_range, figure, world_distances
from ..model.variants import variant_config
from ..training.fit import fit_model
from .capture_scene import capture
from .generate import generate_dataset
from .image_io import save_image
from .neural import evaluate_model, load_scene_model
from .poses import REST_POSE, evaluation_spec


def variant_dataset(obj, captured, variant, folder, rays_per_pose, seed=0, progress=None):
    """Writes the training data ``variant`` learns from into ``folder`` (``variant_capture``);
    ``obj``: the mesh object or a PoseSource (``PosedObject``)."""
    captured, rays_per_pose = variant_capture(captured, variant, rays_per_pose)
    return generate_dataset(obj, captured, folder, rays_per_pose, seed=seed, progress=progress)


def variant_capture(captured, variant, rays_per_pose):
    """(capture, rays per pose) of the data ``variant`` learns from: the walked segments of
    every captured pose, or, for a single-pose variant (``lsnif``), of the rest pose alone
    with as many rays as all poses together (the same data budget)."""
    if not variant_config(variant).deformed_data and captured.mode != "static":
        return (dataclasses.replace(captured, poses=[REST_POSE]),
                rays_per_pose * len(captured.poses))
    return captured, rays_per_pose


def evaluation_poses(obj, resolution, spec, rest=False, count=None, trained=None):
    """A capture of ``obj`` (corners left to per-pose work) whose ``count`` poses (default
    ``spec.count``) are evaluation poses disjoint from the training poses (``trained``, a
    model's stored training poses, else those of the training ``spec``), or ``count`` views
    of the rest pose with ``rest``. A request that cannot be disjoint raises a VDNIFError
    naming the object (``poses.make_poses``)."""
    count = count or spec.count
    if rest:
        captured = capture(obj, resolution, dataclasses.replace(spec, count=1),
                           deform_corners=False)
        return dataclasses.replace(captured, poses=[REST_POSE] * count)
    return capture(obj, resolution, evaluation_spec(spec, count, trained),
                   deform_corners=False)


def model_capture(obj, metadata, spec, evaluation=False, count=None, rest=False,
                  resolution=None):
    """``obj`` captured again as the model of ``metadata`` (its ModelMetadata) was trained
    on it: at the model's resolution (``resolution``: one asked for instead, which
    ``neural.load_scene_model`` refuses unless it is the model's), corners left to per-pose
    work. Its poses: one of ``spec``, for rendering, or with ``evaluation`` ``count``
    evaluation poses (default ``spec.count``) disjoint from the model's training poses, or
    views of the rest pose with ``rest`` (``evaluation_poses``). Without a model
    (``metadata`` None) ``resolution`` is required and the poses avoid those of ``spec``."""
    resolution = resolution or metadata.grid.resolution
    if not evaluation:
        return capture(obj, resolution, dataclasses.replace(spec, count=1),
                       deform_corners=False)
    trained = None if metadata is None else list(metadata.train_poses)
    return evaluation_poses(obj, resolution, spec, rest=rest, count=count, trained=trained)


def evaluate_file(obj, captured, model_path, width, height, device="auto", progress=None,
                  viewpoints=None, seen=False, loaded=None):
    """(report, views) of the model file on the poses of ``captured``, with the model's
    training figures and size added to the report (``seen``: see ``evaluate_model``;
    ``loaded``: see ``neural.load_scene_model``)."""
    model = load_scene_model(model_path, captured, device, loaded)
    report, views = evaluate_model(obj, captured, model, width, height, viewpoints, progress,
                                   seen)
    training = model.metadata.training
    report["config"] = {"network": model.metadata.network_config.to_dict(),
                        "train": dict(training.config)}
    report["timings"].update(train_s=training.seconds,
                             train_samples_per_s=training.samples_per_s,
                             train_steps=training.steps)
    # The loss weighting's final s_i: at the recipe they show whether it balanced the tasks or
    # only followed its learning rate (DESIGN.md section 8, uncertainty weighting).
    report["log_variances"] = dict(training.log_variances)
    report["model_bytes"] = pathlib.Path(model_path).stat().st_size
    return report, views


def write_passes(folder, passes, height, width, world_scale=None, prefix="", slots=None,
                 suffix=""):
    """Writes every pass as a PNG for looking and an EXR for use (distance in world units
    when ``world_scale`` is given, material as the object's slot with the used-slot table
    ``slots``, see ``Passes.with_slots``), named ``{prefix}{pass}{suffix}`` (a sequence's
    frame: ``animation.frame_suffix``); returns the written paths. Writes with Blender's
    image API: call it on Blender's main thread."""
    folder = pathlib.Path(folder)
    data = passes if world_scale is None else world_distances(passes, world_scale)
    data = data if slots is None else data.with_slots(slots)
    shown = images.display(data, height, width, distance_range(data))
    shown["hit"] = np.repeat(images.raw(data, height, width)["hit"], 3, axis=2)
    written = [save_image(folder / f"{prefix}{name}{suffix}.png", image)
               for name, image in shown.items()]
    written += [save_image(folder / f"{prefix}{name}{suffix}.exr", image)
                for name, image in images.raw(data, height, width).items()]
    return written


def write_view(folder, result, height, width, slots=None, references=False, suffix=""):
    """Writes a RenderResult's passes (``write_passes``), and with ``references`` those of
    its true and embedded references, prefixed ``true-`` and ``embedded-``; returns the
    written paths."""
    written = write_passes(folder, result.predicted, height, width, result.world_scale,
                           slots=slots, suffix=suffix)
    if references:
        for name in ("true", "embedded"):
            written += write_passes(folder, getattr(result, name), height, width,
                                    result.world_scale, prefix=f"{name}-", slots=slots,
                                    suffix=suffix)
    return written


def write_figures(folder, view, height, width, object_size):
    """The comparison figures of one view against each reference, and the error heat maps
    against the true reference; returns {name: path}."""
    folder = pathlib.Path(folder)
    paths = {}
    for reference in ("true", "embedded"):
        paths[f"figure_vs_{reference}"] = save_image(
            folder / f"figure-vs-{reference}.png",
            figure(view[reference], view["predicted"], height, width, object_size))
    errors = images.error_images(view["predicted"], view["true"], height, width, object_size)
    for name in ("distance", "normal"):
        paths[f"error_{name}"] = save_image(folder / f"error-{name}.png", errors[name])
    return paths


def train_variant(obj, captured, variant, folder, rays_per_pose, out, overrides, seed=0,
                  progress=None):
    """Dataset + training of ``variant`` in one step: (TrainResult, summary)."""
    header = variant_dataset(obj, captured, variant, folder, rays_per_pose, seed)
    result, summary = fit_model(folder, variant, out, overrides, progress=progress)
    summary["dataset"] = {"folder": str(folder), "rays": header.counts.rays,
                          "segments": header.counts.segments,
                          "seconds": header.timings["total_s"]}
    return result, summary
