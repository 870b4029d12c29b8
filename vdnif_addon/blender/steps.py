"""The pipeline's steps as the batch commands and the experiments chain them: datasets for a
variant, training, evaluation on unseen poses, and the images they write."""

import dataclasses
import pathlib

import numpy as np

from ..errors import VDNIFError
from ..geometry.capture import ARMATURE_COPY
from ..inference import images
from ..inference.evaluation import (
    DistanceScale,
    figure,
    secondary_view_images,
    world_distances,
)
from ..inference.exr import write_multilayer
from ..kernels import runtime
from ..model.variants import variant_config
from ..passes import (
    COMPOSITOR_PASSES,
    SECONDARY_PASSES,
    SHADED_COMPOSITOR,
    SHADED_PASS,
    TOGGLED_PASSES,
    VIEW_LAYER,
)
from ..pose_sets import TEST_POSES
from ..posed.generate import generate_dataset
from ..posed.render import evaluate_model, load_scene_model
from ..settings import DEFAULT_PRECISION
from ..training.fit import fit_model
from ..training.history import plot
from .capture_scene import capture
from .follow_choice import choose_follow
from .image_io import save_image
from .poses import REST_POSE, evaluation_spec
from .uncaptured import check_captured


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


def training_follow(obj, resolution, spec, say=None):
    """How the corners of ``obj`` follow it in a model trained at ``resolution`` on the
    poses of ``spec``: as ``follow_choice.choose_follow`` measures best (once a job: every
    capture of the job takes it from here); ``say(line)`` hears the choice and its seconds
    where there was one to make, or where a separate piece slides (``pieces.sliding``)."""
    choice = choose_follow(obj, resolution, spec)
    if say is not None and (choice.errors or choice.sliding):
        say(choice.describe())
    return choice.follow


def training_capture(obj, resolution, spec, say=None):
    """The capture a model of ``obj`` trains on (corners left to per-pose work), its
    corners following as ``training_follow`` chooses (``say``: see there)."""
    return capture(obj, resolution, spec, deform_corners=False,
                   follow=training_follow(obj, resolution, spec, say))


def evaluation_poses(obj, resolution, spec, rest=False, count=None, trained=None,
                     pose_set=TEST_POSES, follow=None):
    """A capture of ``obj`` (corners left to per-pose work) whose ``count`` poses (default
    ``spec.count``) are evaluation poses of ``pose_set`` (``pose_sets.POSE_SETS``) disjoint
    from the training poses (``trained``, a model's stored training poses, else those of the
    training ``spec``), or ``count`` views of the rest pose with ``rest``; its corners
    follow as ``follow`` says (the model's: ``capture``). A request that cannot be
    disjoint raises a VDNIFError naming the object (``poses.make_poses``)."""
    count = count or spec.count
    if rest:
        captured = capture(obj, resolution, dataclasses.replace(spec, count=1),
                           deform_corners=False, follow=follow)
        return dataclasses.replace(captured, poses=[REST_POSE] * count)
    return capture(obj, resolution, evaluation_spec(spec, count, trained, pose_set),
                   deform_corners=False, follow=follow)


def model_capture(obj, metadata, spec, evaluation=False, count=None, rest=False,
                  resolution=None, pose_set=TEST_POSES):
    """``obj`` captured again as the model of ``metadata`` (its ModelMetadata) was trained
    on it: at the model's resolution (``resolution``: one asked for instead, which
    ``neural.load_scene_model`` refuses unless it is the model's), corners left to per-pose
    work. Its poses: one of ``spec``, for rendering, or with ``evaluation`` ``count``
    evaluation poses (default ``spec.count``) of ``pose_set`` disjoint from the model's
    training poses, or views of the rest pose with ``rest`` (``evaluation_poses``). The corners
    follow as the model's did (its ``corners_follow``). Without a model (``metadata`` None)
    ``resolution`` is required, the poses avoid those of ``spec`` and the corners follow as
    ``deform.check_deformers`` chooses."""
    resolution = resolution or metadata.grid.resolution
    follow = None if metadata is None else model_follow(obj, metadata.corners_follow)
    if not evaluation:
        return capture(obj, resolution, dataclasses.replace(spec, count=1),
                       deform_corners=False, follow=follow)
    trained = None if metadata is None else list(metadata.train_poses)
    return evaluation_poses(obj, resolution, spec, rest=rest, count=count, trained=trained,
                            pose_set=pose_set, follow=follow)


def model_follow(obj, follow):
    """``follow``, how the corners of a model of ``obj`` follow it (None: as the capture
    chooses), once checked: where they follow copies of the armature and lattice modifiers
    that no longer capture ``obj`` (a modifier or key added to the rig since), a VDNIFError
    naming what they miss, as the copied corners would stay while the mesh moves."""
    if follow == ARMATURE_COPY:
        try:
            check_captured(obj)
        except VDNIFError as error:
            raise VDNIFError(f"{error}; the model's corners follow copies of the armature "
                             "and lattice modifiers, which miss that: retrain the model on "
                             "the rig as it is now") from None
    return follow


def evaluate_file(obj, captured, model_path, width, height, device="auto", progress=None,
                  viewpoints=None, seen=False, loaded=None, secondary=None,
                  precision=DEFAULT_PRECISION):
    """(report, views) of the model file on the poses of ``captured``, with the model's
    training figures and size added to the report (``seen``: see ``evaluate_model``;
    ``loaded`` and ``precision``: see ``neural.load_scene_model``; ``secondary``: the AO
    and shadow passes' ``SecondarySettings``, see ``evaluate_model``). The kernels are
    compiled or loaded first, timed apart (``timings.kernels_s``), so that no speed
    includes them."""
    model = load_scene_model(model_path, captured, device, loaded, precision)
    kernels_s = runtime.load_all(runtime.device(model.device))   # apart from the speeds
    report, views = evaluate_model(obj, captured, model, width, height, viewpoints, progress,
                                   seen, secondary)
    report["timings"]["kernels_s"] = kernels_s
    training = model.metadata.training
    report["config"] = {"network": model.metadata.network_config.to_dict(),
                        "train": dict(training.config)}
    report["timings"].update(train_s=training.seconds,
                             train_samples_per_s=training.samples_per_s,
                             train_steps=training.steps)
    # The loss weighting's final s_i: at the recipe they show whether it balanced the tasks or
    # only followed its learning rate (DESIGN.md section 8, uncertainty weighting).
    report["log_variances"] = dict(training.log_variances)
    # The calibrated thresholds decide the trade of holes for extras the report measures.
    report["thresholds"] = model.metadata.thresholds.to_dict()
    report["model_bytes"] = pathlib.Path(model_path).stat().st_size
    return report, views


def write_passes(folder, passes, height, width, world_scale=None, prefix="", slots=None,
                 frame=None, world_matrix=None, secondary=None, secondary_names=TOGGLED_PASSES,
                 scale=None, shaded=None):
    """Writes a PNG preview per pass (transparent where rays miss) and one multilayer EXR of
    the compositor's passes (``images.compositor_passes``): distance in world units when
    ``world_scale`` is given, normals in world space with the object's ``world_matrix``
    (4, 4), material as the object's slot with the used-slot table ``slots``, see
    ``Passes.with_slots``. With ``secondary`` (SecondaryPasses of the same rays) the passes
    ``secondary_names`` of it go into the same EXR as AO and Shadow, and beside it as PNGs;
    so does the shaded image ``shaded`` (R, 3) as Shaded where ``secondary_names`` holds
    "shaded" (``passes.TOGGLED_PASSES``).
    A ``frame`` number goes into the names as Blender numbers image sequences
    (``normal.0030.png``, ``passes.0030.exr``). ``scale``: the ``DistanceScale`` shared with
    the images this one is compared with (default: its own). Returns the written paths.
    Writes with Blender's image API: call it on Blender's main thread."""
    folder = pathlib.Path(folder)
    data = passes if world_scale is None else world_distances(passes, world_scale)
    data = data if slots is None else data.with_slots(slots)
    number = frame_number(frame)
    near_far = (scale or DistanceScale())(data)
    written = [save_image(folder / f"{prefix}{name}{number}.png", image) for name, image
               in images.previews(data, height, width, near_far).items()]
    normal_matrix = None if world_matrix is None else np.linalg.inv(
        np.asarray(world_matrix, np.float64)[:3, :3]).T
    layers = images.compositor_passes(data, height, width, normal_matrix)
    channels = dict(COMPOSITOR_PASSES)
    if secondary is not None:
        extra = images.secondary_compositor(secondary, height, width, secondary_names)
        layers.update(extra)
        channels.update(dict.fromkeys(extra, "RGB"))
        written += write_secondary(folder, secondary, height, width, prefix, frame,
                                   secondary_names)
    if shaded is not None and SHADED_PASS in secondary_names:
        layers.update(images.shaded_compositor(shaded, height, width))
        channels.update(SHADED_COMPOSITOR)
        alpha = passes.hit.reshape(height, width, 1).astype(np.float32)
        written.append(save_image(folder / f"{prefix}{SHADED_PASS}{number}.png", np.concatenate(
            [images.shaded_display(shaded, height, width), alpha], axis=2)))
    written.append(write_multilayer(folder / f"{prefix}passes{number}.exr", layers, channels,
                                    VIEW_LAYER))
    return written


def write_training_plot(path, history):
    """Writes the loss plot of training's progress records (``history.plot``) as a PNG."""
    return save_image(path, plot(history))


def write_view(folder, result, height, width, slots=None, references=False, frame=None,
               secondary_names=TOGGLED_PASSES, scale=None, prefix=""):
    """Writes a RenderResult's passes (``write_passes``, normals in world space with the
    pose's world matrix), with ``references`` those of its true and embedded references,
    prefixed ``true-`` and ``embedded-``, each with its AO, shadow and shaded passes
    ``secondary_names`` when it has them (into its EXR, PNGs beside it), every distance
    preview on one
    ``DistanceScale`` (``scale``: a sequence's, default this view's own); ``prefix`` goes
    before every name. Returns the written paths."""
    sources = {"": result.predicted}
    if references:
        sources.update({f"{name}-": getattr(result, name) for name in ("true", "embedded")})
    scale = scale or DistanceScale()
    scale(*(world_distances(passes, result.world_scale) for passes in sources.values()))
    secondary, shaded = result.secondary or {}, result.shaded or {}
    written = []
    for source, passes in sources.items():
        name = source.rstrip("-") or "predicted"
        written += write_passes(folder, passes, height, width, result.world_scale,
                                prefix=prefix + source, slots=slots, frame=frame,
                                world_matrix=result.matrix_world,
                                secondary=secondary.get(name),
                                secondary_names=secondary_names, scale=scale,
                                shaded=shaded.get(name))
    return written


def frame_number(frame):
    """What a sequence's file names hold before the extension, as Blender numbers image
    sequences (``.0030``; a negative frame keeps its sign); nothing without a frame."""
    return "" if frame is None else f".{round(frame):04d}"


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
    if "secondary" in view:             # reference | predicted | error, a row per pass
        shown = secondary_view_images(view["secondary"]["true"],
                                      view["secondary"]["predicted"], height, width,
                                      view.get("shaded"))
        rows = [[shown[source][name] for source in ("reference", "predicted", "error")]
                for name in TOGGLED_PASSES if name in shown["reference"]]
        paths["figure_secondary_vs_true"] = save_image(
            folder / "figure-secondary-vs-true.png", images.comparison_figure(rows))
    return paths


def write_secondary(folder, passes, height, width, prefix="", frame=None,
                    names=SECONDARY_PASSES):
    """Writes the PNG previews of the AO and shadow passes ``names`` (``SecondaryPasses``),
    a ``frame`` numbered as in ``write_passes`` (their values go into its EXR); returns the
    written paths."""
    folder = pathlib.Path(folder)
    shown = images.secondary_images(passes, height, width)["display"]
    number = frame_number(frame)
    return [save_image(folder / f"{prefix}{name}{number}.png", shown[name])
            for name in SECONDARY_PASSES if name in names]


def train_variant(obj, captured, variant, folder, rays_per_pose, out, overrides, seed=0,
                  progress=None):
    """Dataset + training of ``variant`` in one step: (TrainResult, summary)."""
    header = variant_dataset(obj, captured, variant, folder, rays_per_pose, seed)
    result, summary = fit_model(folder, variant, out, overrides, progress=progress)
    summary["dataset"] = {"folder": str(folder), "rays": header.counts.rays,
                          "segments": header.counts.segments,
                          "seconds": header.timings["total_s"]}
    return result, summary
