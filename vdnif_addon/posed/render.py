"""A trained model at work on a Blender scene: load it for a captured object, render its
passes for a pose and a camera, and evaluate it against both references on unseen poses
(DESIGN sections 9 and 10). The numerics are in ``render`` and ``evaluation``."""

import math
import statistics
import time
from dataclasses import dataclass

import numpy as np

from ..errors import VDNIFError
from ..inference.evaluation import (
    check_model_fits,
    compare_both,
    compare_secondary_both,
    compare_shaded_both,
    concatenated,
    speed_figures,
)
from ..inference.neural_render import neural_passes
from ..inference.secondary import (
    embedded_occluded,
    exact_occluded,
    model_offset,
    neural_occluded,
    secondary_views,
)
from ..inference.shading import settings_lighting, shaded_views
from ..kernels.cast import MeshCaster
from ..passes import Passes, SecondaryPasses
from ..pose_sets import pose_key
from ..settings import DEFAULT_PRECISION, TERMINATOR_BAND
from ..text import article
from ..tracing.rays import camera_rays as pinhole_rays
from ..tracing.rays import orbit_rays, orbit_viewpoints, transform_rays
from ..tracing.references import embedded_passes, true_reference
from .geometry import PosedObject


@dataclass
class SceneModel:
    """A model file loaded for one captured object (checked to fit it)."""

    network: object            # IntersectionNetwork in eval mode on ``device``
    metadata: object           # the file's ModelMetadata (model_file.load_model)
    grid: object               # the capture's VoxelGrid, equal to the model's
    path: str
    device: object             # torch.device

    @property
    def variant(self):
        return self.metadata.variant

    @property
    def albedo_table(self):
        return self.metadata.albedo_colors()

    def secondary_offset(self, object_size):
        """Local units the secondary rays of its hits start off them (``network_offset``:
        its voxel and held-out distance error), an object unit ``object_size`` local ones."""
        return model_offset(self.metadata, object_size, self.grid.voxel_size)


def load_scene_model(path, capture, device="auto", loaded=None, precision=DEFAULT_PRECISION):
    """Loads the model file ``path`` for ``capture``'s object (``loaded``: its
    ``model_file.load_model`` result when the caller read it already), its MLPs to run in
    ``precision`` as ``network.resolve_precision`` resolves it for the device; a file that
    is corrupt, of another format, or trained on another object or resolution, or bfloat16
    on a device without it, raises a one-line VDNIFError."""
    from ..model.model_file import load_model
    from ..model.network import resolve_precision
    from ..training.distributed import resolve_device

    network, metadata = load_model(path) if loaded is None else loaded
    check_model_fits(path, metadata, capture.mesh, capture.grid)
    device = resolve_device(device)
    network.precision = resolve_precision(precision, device)
    return SceneModel(network=network.to(device), metadata=metadata, grid=capture.grid,
                      path=str(path), device=device)


@dataclass
class RenderResult:
    """The passes of one view, in the object's local units (see ``world_scale``)."""

    predicted: Passes
    true: Passes               # None unless references were asked for
    embedded: Passes           # None unless references were asked for
    timings: dict              # prepare_s, walk_s, network_s, render_s, rays, segments
    object_size: float         # one object unit in local units
    world_scale: np.ndarray    # (R,) local distance / world distance per ray
    inverted_cells: int
    # {"predicted", "true", ...: SecondaryPasses} (``secondary.secondary_views``) when asked
    secondary: dict = None
    matrix_world: np.ndarray = None    # (4, 4) the object's world matrix in the pose
    # with ``secondary``: {"predicted", "true", "embedded": (R, 3) shaded image} of each
    # primary pass with its own secondary passes, and {same: (R,) N.L of its hits, NaN on a
    # miss} (``shading.shaded_views``)
    shaded: dict = None
    cosines: dict = None


def render_rays(obj, capture, model, pose, origins, directions, references=False,
                secondary=None):
    """Renders world-space rays (N, 3) of ``obj`` in ``pose`` (a pose dict; the current
    frame is ``{"frame": scene.frame_current}``) with the network, and with the true and
    embedded references when asked; the AO and shadow passes too with ``secondary`` (a
    ``SecondarySettings``, its light in the object's local space). ``obj``: a mesh object
    or a PoseSource."""
    with PosedObject(obj, capture, model.device) as posed_object:
        return render_world(model, posed_object, posed_object.geometry(pose), origins,
                            directions, references, secondary)


def render_world(model, posed_object, geometry, origins, directions, references=False,
                 secondary=None):
    """RenderResult of world-space rays for one posed geometry (its world matrix maps them
    into the object's local space; ``world_scale`` maps the distances back)."""
    inverse = np.linalg.inv(geometry.matrix_world)
    local_origins, local_directions, scale = transform_rays(origins, directions, inverse)
    result = render_local(model, posed_object, geometry, local_origins, local_directions,
                          references, secondary)
    result.world_scale = scale
    return result


def render_orbit(obj, capture, model, pose, width, height, references=False, secondary=None):
    """``render_rays`` through the first orbit viewpoint around the posed object, for a
    scene without a camera (rays in local space: world distances are scaled back)."""
    with PosedObject(obj, capture, model.device) as posed_object:
        geometry = posed_object.geometry(pose)
        origins, directions = orbit_view(geometry, orbit_viewpoints(1)[0], width, height)
        return render_orbit_rays(model, posed_object, geometry, origins, directions,
                                 references, secondary)


def render_orbit_rays(model, posed_object, geometry, origins, directions, references=False,
                      secondary=None):
    """RenderResult of local rays (an orbit view's) for one posed geometry, with the world
    scale of its world matrix."""
    result = render_local(model, posed_object, geometry, origins, directions, references,
                          secondary)
    linear = geometry.matrix_world[:3, :3]
    result.world_scale = 1.0 / np.linalg.norm(directions @ linear.T, axis=1)
    return result


def orbit_view(geometry, direction, width, height):
    """Local rays of an orbit camera on ``direction`` around a posed geometry's bounds."""
    return orbit_rays(geometry.vertices.min(0), geometry.vertices.max(0), direction, width,
                      height)


def camera_view(camera, width, height):
    """(world matrix (4, 4), horizontal field of view in degrees, lens shift (right, up) in
    image widths, clip range (start, end) in world units along the view axis) of a
    perspective Blender camera object rendering a ``width`` x ``height`` image (its sensor
    fit respected): what ``view_rays`` and ``render_view`` need, read from Blender."""
    if camera is None:
        raise VDNIFError("no camera: the scene has no active camera and none was named")
    if camera.type != "CAMERA":
        raise VDNIFError(f"object '{camera.name}' is {article(camera.type.lower())}, not a camera")
    data = camera.data
    if data.type != "PERSP":
        raise VDNIFError(f"camera '{camera.name}' is {data.type.lower()}: only perspective "
                         "cameras are supported")
    # AUTO: the sensor width spans the larger image side; otherwise the named sensor side.
    if data.sensor_fit == "AUTO":
        vertical, angle = height > width, data.angle_x
    else:
        vertical = data.sensor_fit == "VERTICAL"
        angle = data.angle_y if vertical else data.angle_x
    half = math.tan(angle / 2) * (width / height if vertical else 1.0)
    # Blender's shift is in units of the fitted side: the height's, where that is the width's
    # height / width
    fitted = height / width if vertical else 1.0
    shift = (data.shift_x * fitted, data.shift_y * fitted)
    return (np.array(camera.matrix_world, np.float64), math.degrees(2 * math.atan(half)),
            shift, (data.clip_start, data.clip_end))


def view_rays(view, width, height):
    """World-space rays (origins, directions), (H*W, 3) each, of a pinhole ``view``
    (world matrix, horizontal field of view in degrees, and a camera's lens shift where it
    gives one: ``camera_view``; the 3D Viewport's gives the first two)."""
    matrix, fov, *camera = view
    return pinhole_rays(matrix, fov, width, height, *camera[:1])


def render_view(model, posed_object, geometry, view, width, height, references=False,
                secondary=None):
    """``render_world`` of a pinhole ``view``'s rays with its camera's clip range, as
    Blender clips: a surface nearer than the clip start along the view axis is not seen
    (the ray starts there and sees what lies behind it), one beyond the clip end is a
    miss."""
    origins, directions = view_rays(view, width, height)
    if len(view) < 4:
        return render_world(model, posed_object, geometry, origins, directions, references,
                            secondary)
    matrix, (near, far) = np.asarray(view[0], np.float64), view[3]
    forward = -matrix[:3, 2] / np.linalg.norm(matrix[:3, 2])
    cosine = directions @ forward                          # > 0 inside the frustum
    start = near / cosine
    result = render_world(model, posed_object, geometry, origins + directions * start[:, None],
                          directions, references, secondary)
    skipped, reach = start * result.world_scale, (far - near) / cosine * result.world_scale
    for name in ("predicted", "true", "embedded"):
        passes = getattr(result, name)
        if passes is not None:
            kept = passes.hit & (passes.distance <= reach)
            setattr(result, name, Passes(
                hit=kept, distance=np.where(kept, passes.distance + skipped, 0.0),
                normal=np.where(kept[:, None], passes.normal, 0.0),
                albedo=np.where(kept[:, None], passes.albedo, 0).astype(passes.albedo.dtype),
                material=np.where(kept, passes.material, 0).astype(passes.material.dtype)))
    for name, passes in (result.secondary or {}).items():     # from the hits still seen
        kept = passes.hit & getattr(result, "true" if name.endswith("_true_hit") else name).hit
        result.secondary[name] = SecondaryPasses(
            hit=kept, ao=np.where(kept, passes.ao, 0).astype(passes.ao.dtype),
            lit=passes.lit & kept, facing=passes.facing & kept)
    if result.shaded is not None:             # a hit beyond the clip end shows the world
        world = np.asarray(settings_lighting(secondary).world, np.float32)
        for name, image in result.shaded.items():
            kept = getattr(result, name).hit
            result.shaded[name] = np.where(kept[:, None], image, world).astype(np.float32)
            result.cosines[name] = np.where(kept, result.cosines[name], np.nan).astype(
                np.float32)
    return result


def camera_rays(camera, width, height):
    """World-space rays (origins, directions), (H*W, 3) each, of a perspective Blender
    camera object rendering a ``width`` x ``height`` image (``camera_view``)."""
    return view_rays(camera_view(camera, width, height), width, height)


def evaluate_model(obj, capture, model, width, height, viewpoints=None, progress=None,
                   seen=False, secondary=None):
    """Renders every pose of ``capture`` (the evaluation poses) from an orbit camera each
    (``viewpoints`` (P, 3), default a Fibonacci sphere) with the network and both
    references. Returns (report, views): the JSON-ready metrics and timings, and per pose
    {"predicted", "true", "embedded"} Passes in local units whose material pass holds the
    object's material slots (``Passes.with_slots``).

    Deformed poses must be unseen: evaluation poses that the model was trained on are
    refused (a VDNIFError naming the object) unless ``seen`` says the model was trained on
    them by design (the per-pose upper bound). Views of the rest pose and a static object's
    one pose may be the training pose; ``unseen_poses`` says whether they are. Render
    speeds are given only for a model that predicts hits (``evaluation.speed_figures``).
    With ``secondary`` (``SecondarySettings``) the AO and shadow passes are compared too,
    and each view holds them under "secondary".
    """
    poses = capture.poses
    unseen = _unseen(poses, model.metadata.train_poses)
    if not (unseen or seen or capture.mode == "static" or all(p.get("rest") for p in poses)):
        raise VDNIFError(f"'{obj.name}': the evaluation poses include poses that model "
                         f"'{model.path}' was trained on: evaluate on unseen poses")
    viewpoints = orbit_viewpoints(len(poses)) if viewpoints is None else viewpoints
    views, results = [], []
    with PosedObject(obj, capture, model.device) as posed_object:
        for index, pose in enumerate(poses):
            geometry = posed_object.geometry(pose)
            origins, directions = orbit_view(geometry, viewpoints[index], width, height)
            result = render_local(model, posed_object, geometry, origins, directions, True,
                                  secondary)
            results.append(result)
            views.append({name: getattr(result, name).with_slots(capture.mesh.material_slots)
                          for name in ("predicted", "true", "embedded")})
            if secondary is not None:
                views[-1].update(secondary=result.secondary, shaded=result.shaded,
                                 cosines=result.cosines)
            if progress is not None:
                progress(index + 1, len(poses))
    joined = concatenated(views)
    render_s = sum(r.timings["render_s"] for r in results)
    h = capture.grid.voxel_size
    metrics = compare_both(joined["predicted"], joined["true"], joined["embedded"],
                           capture.mesh, h)
    timings, withheld = speed_figures({
        "render_rays_per_s": sum(r.timings["rays"] for r in results) / render_s,
        "render_segments_per_s": sum(r.timings["segments"] for r in results) / render_s,
        "prepare_pose_s": statistics.median(r.timings["prepare_s"] for r in results),
        "network_fraction": sum(r.timings["network_s"] for r in results) / render_s,
    }, metrics["vs_true"])
    exact_s = sum(r.timings["exact_cast_s"] for r in results)
    timings.update(   # the exact path (Warp's refit BVH), timed as the network on the same rays
        exact_rays_per_s=sum(r.timings["rays"] for r in results) / exact_s if exact_s > 0
        else None,
        exact_prepare_s=statistics.median(r.timings["exact_prepare_s"] for r in results))
    report = {
        "object": capture.mesh.name, "mode": capture.mode, "variant": model.variant,
        "model": model.path, "resolution": capture.grid.resolution, "poses": len(poses),
        "width": width, "height": height, "voxel_size": h, "unseen_poses": unseen,
        "precision": model.network.precision, **metrics,
        "per_pose": [dict(compare_both(r.predicted, r.true, r.embedded, capture.mesh, h),
                          inverted_cells=r.inverted_cells) for r in results],
        "timings": timings,
        "speed_withheld": withheld,
        "truncated_rays": sum(r.timings["truncated_rays"] for r in results),
    }
    if secondary is not None:
        size = capture.mesh.size
        _secondary_report(report, results, secondary, model.secondary_offset(size), size)
    return report, views


def _secondary_report(report, results, settings, network_offset, object_size):
    """Adds the AO, shadow and shaded metrics (joined and per pose), their settings (the
    network's offset ``network_offset`` local units, an object unit ``object_size`` local
    ones, the terminator band) and the network's secondary rays per second to an evaluation
    ``report``."""
    joined = {name: SecondaryPasses.concatenate([r.secondary[name] for r in results])
              for name in results[0].secondary}
    shaded, cosines = ({name: np.concatenate([getattr(r, field)[name] for r in results])
                        for name in results[0].shaded} for field in ("shaded", "cosines"))
    for reference, metrics in compare_secondary_both(joined).items():
        report[reference].update(metrics)
    for reference, metrics in compare_shaded_both(shaded, joined, cosines,
                                                  TERMINATOR_BAND).items():
        report[reference].update(metrics)
    for row, result in zip(report["per_pose"], results):
        for reference, metrics in compare_secondary_both(result.secondary).items():
            row[reference].update(metrics)
        for reference, metrics in compare_shaded_both(result.shaded, result.secondary,
                                                      result.cosines, TERMINATOR_BAND).items():
            row[reference].update(metrics)
    report["secondary"] = dict(settings.describe(network_offset, object_size),
                               **settings_lighting(settings).describe(),
                               terminator_band=TERMINATOR_BAND)
    rays = sum(r.timings["secondary_rays"] for r in results)
    seconds = sum(r.timings["secondary_s"] for r in results)
    report["timings"]["secondary_rays_per_s"] = (
        rays / seconds if seconds > 0 and report["speed_withheld"] is None else None)


def render_local(model, posed_object, geometry, origins, directions, references=False,
                 secondary=None):
    """RenderResult of local rays for one posed geometry (``secondary``: see
    ``render_rays``); touches no Blender data."""
    mesh = posed_object.capture.mesh
    start = time.perf_counter()
    predicted, stats = neural_passes(model.network, model.grid, model.albedo_table,
                                     geometry.cells, origins, directions, model.device)
    render_s = time.perf_counter() - start
    true = embedded = None
    exact = {}
    if references:
        # The exact path the extension ships: Warp's BVH of the deformed mesh, refit to the
        # pose (its preparation, apart as the network's is), then the casts (its rays/s).
        start = time.perf_counter()
        caster = geometry.mesh_caster(mesh.triangles)
        refit_s = time.perf_counter() - start
        true = true_reference(mesh, caster, origins, directions)
        exact = dict(exact_prepare_s=refit_s,
                     exact_cast_s=time.perf_counter() - start - refit_s)
        embedded, _, _ = embedded_passes(geometry.cells, mesh, posed_object.rest_caster,
                                         origins, directions)
    timings = dict(prepare_s=geometry.prepare_s, walk_s=stats["walk_s"],
                   network_s=stats["network_s"], render_s=render_s, rays=len(origins),
                   segments=stats["segments"], truncated_rays=stats["truncated"], **exact)
    result = RenderResult(predicted=predicted, true=true, embedded=embedded, timings=timings,
                          object_size=mesh.size, world_scale=np.ones(len(origins)),
                          inverted_cells=geometry.inverted_cells(),
                          matrix_world=geometry.matrix_world)
    if secondary is not None:
        _render_secondary(result, model, posed_object, geometry, origins, directions,
                          secondary)
    return result


def _render_secondary(result, model, posed_object, geometry, origins, directions, settings):
    """The AO and shadow passes of ``result``'s primary hits (``secondary.secondary_views``):
    the network's, and each reference's where the result has them."""
    mesh, stats = posed_object.capture.mesh, {}
    offset = model.secondary_offset(mesh.size)
    occluders = {"neural": neural_occluded(model.network, model.grid, model.albedo_table,
                                           geometry.cells, offset, model.device, stats)}
    primaries = {"predicted": result.predicted}
    if result.true is not None:
        occluders["exact"] = exact_occluded(MeshCaster(geometry.vertices, mesh.triangles))
        occluders["embedded"] = embedded_occluded(geometry.cells, mesh,
                                                  posed_object.rest_caster)
        primaries.update(true=result.true, embedded=result.embedded)
    result.secondary = secondary_views(primaries, origins, directions, occluders, mesh.size,
                                       settings, offset)
    result.shaded, result.cosines = shaded_views(primaries, result.secondary, origins,
                                                 directions, settings_lighting(settings))
    result.timings.update(secondary_rays=stats.get("rays", 0),
                          secondary_s=stats.get("seconds", 0.0))


def _unseen(poses, train_poses):
    """True when no evaluation pose equals a training pose (compared as ``pose_key``:
    the model's training poses come back from its file with string keys)."""
    trained = {pose_key(pose) for pose in train_poses}
    return not any(pose_key(pose) in trained for pose in poses)
