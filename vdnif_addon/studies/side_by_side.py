"""Side by side with the classical baselines (DESIGN section 10, speed and size).

Per pose, every classical baseline (``baselines``: Blender's BVHTree rebuilt, Warp's mesh BVH
refit, Embree refit and Embree rebuilt) starts from Blender's evaluation of the deformed
mesh, reads its vertices, prepares its BVH and casts every ray; the neural path deforms the
voxel corners and refits the entry BVH over the deformed cells, then renders with a trained
model. A run has one thread setting (1, or every core): the Embree baselines build and cast
on that many threads, Warp's casts are split over that many, torch runs on that many less
the encoder's core (at least one); the neural render renders up to one lane per core of
the setting at once (``walk_lanes``), each on a thread of its own with its share of the
setting's cores (``threads.use_cores``), and one lane's network encodes beside its MLP only
where the setting has a core for it; the BVHTree loop, Warp's refit and its other CPU
launches run on one whatever the setting, and each result says what ran on how many. On
the rest pose, the deformation-aware walk (entry BVH + face intersections) is timed against
the static DDA walk of the same rays: both are Warp kernels with the same segment buffers
and launches. Every figure is timed alternately in one process after one untimed pass and
reported as the median over repeats, so background load affects all sides alike. On CUDA the
clock is read only after the device's queued work is done. With secondary rays
each path also casts the ambient-occlusion and shadow rays of its own primary hits per pose
(below).

Speeds of the neural render come only from a model file that predicts hits: its hit IoU
against the true reference, on the same views in the same run, must reach
``metrics.SPEED_MIN_HIT_IOU`` (``metrics.speed_withheld``); otherwise, and without a model,
they are n/a with the reason. The tables and plots are written by ``side_by_side_report``.

Secondary rays (``side-by-side --secondary``) show whether a neural pose stays cheaper than
a classical one once each primary hit casts ambient-occlusion and shadow rays.

Per pose, after the primary pass of each path, every path casts the secondary rays of its own
primary hits (``inference.secondary.secondary_passes``: ``samples`` cosine-weighted AO rays
per hit up to the AO distance, and a shadow ray towards the light from each hit that faces
it; a hit facing away is in its own shadow without a cast), once at 1 AO sample per pixel
and once at the run's N, so that one run shows how the trade moves with rays per pose. The
neural path answers them through the deformed walk and the network from the network's hits
and normals; Warp's refit BVH and Embree (refit and rebuilt) through the BVH their pose
prepared, from their own first hits and the hit triangle's geometric normal (computed from
the pose's vertices inside the timed step). Every path asks the same question, the first hit
within reach. Blender's BVHTree is left out: its Python loop of ``ray_cast`` casts some
10^5 rays per second, so the AO rays of one pose take longer than every other path's
whole run.

A path's secondary time counts everything after its primary pass: normals, start points,
directions and the casts. Its pose total at S samples is its preparation, its primary pass
and that time. Its tables are written by ``side_by_side_report``.

A scene without a model on the command line gets one trained by the recipe
(``settings.RECIPE``: its resolution for the mesh, poses, rays per pose and steps), kept in a
folder and used again by the next run (``recipe_model``).
"""

import dataclasses
import importlib.metadata
import io
import os
import pathlib
import statistics
import sys
import tempfile
import time

import bpy
import numpy as np
import torch

from .. import threads as thread_use
from ..blender.poses import posed
from ..blender.resolution import recipe_resolution
from ..blender.steps import train_variant, training_capture
from ..errors import VDNIFError
from ..inference.metrics import compare, speed_withheld
from ..inference.neural_render import neural_passes, predict_segments
from ..inference.secondary import (
    exact_occluded,
    mesh_primary,
    neural_occluded,
    secondary_passes,
)
from ..kernels import runtime
from ..model.network import IntersectionNetwork
from ..model.variants import choose_variant
from ..passes import Passes
from ..pose_sets import PoseSpec
from ..posed.geometry import PosedObject
from ..settings import RECIPE, Heads, NetworkConfig
from ..threads import ENCODER_CORES
from ..tracing.rays import orbit_rays, orbit_viewpoints
from ..tracing.references import true_reference
from ..tracing.static_grid import StaticGrid
from ..tracing.traverse import traverse
from .baselines import (
    BASELINES,
    close_baselines,
    evaluation_s,
    make_baselines,
)
from .side_by_side_report import SECONDARY_BASELINES, SECONDARY_PATHS, pose_total
from .side_by_side_scenes import load_side_by_side_scene

NO_MODEL = "no model file for this scene (--model): only a trained model has speeds"
# Keys of a pose record that time the neural render, withheld with its speed.
RENDER_KEYS = ("neural_render_s", "neural_walk_s", "neural_network_s", "neural_segments")

NEURAL_PREFIX = "neural_secondary"
SKIPPED = {"bvhtree": "its Python loop of `ray_cast` (about 10^5 rays/s) would take longer "
                      "than every other path together"}


def compare_paths(obj, capture, model, width, height, repeats, progress=None, device="cpu",
                  threads=1, secondary=None):
    """Times the classical baselines and the neural path on every pose of ``capture`` of
    ``obj`` at the thread setting ``threads`` (see the module), with ``secondary``
    (``SecondarySettings``) each path's secondary rays too (``secondary_record``).

    ``model`` is a ``neural.SceneModel`` (or an object with its ``network``,
    ``albedo_table``, ``device``, ``path`` and ``variant``), or None: then the neural render
    and the network are not run (n/a). Rays are an orbit camera per pose, ``width`` x
    ``height``, in the object's local space. Returns a JSON-ready dict: per-repeat records,
    their medians, rays/s and the ratios (median over repeats of each repeat's ratio), the
    hits of each baseline against the true reference, and bytes.
    """
    if repeats < 1:
        raise VDNIFError(f"side by side of '{obj.name}': repeats {repeats} must be at least 1")
    if width < 1 or height < 1:
        raise VDNIFError(f"side by side of '{obj.name}': image size {width}x{height} must be "
                         "at least 1x1")
    if threads < 1:
        raise VDNIFError(f"side by side of '{obj.name}': thread setting {threads} must be "
                         "at least 1")
    device = runtime.device(device if model is None else model.device)
    kernels_s = runtime.load_all(device)        # a first compile, said apart from the speeds
    viewpoints = orbit_viewpoints(len(capture.poses))
    static_grid = StaticGrid(capture.grid, device)
    torch_threads = torch.get_num_threads()
    torch.set_num_threads(torch_setting(threads))
    thread_use.use_encoder_threads(threads)
    thread_use.use_cores(threads)
    baselines, embree = make_baselines(capture.mesh, device, threads)
    runs, checks = [], []
    try:
        with PosedObject(obj, capture, device) as posed_object:
            rest = posed_object.rest_geometry()
            rest_rays = [orbit_rays(capture.mesh.vertices.min(0), capture.mesh.vertices.max(0),
                                    view, width, height) for view in viewpoints]

            def pose_record(pose, view, check=False):
                return _pose_record(obj, posed_object, baselines, model, pose, view, width,
                                    height, check, secondary)

            # one untimed pass: kernels load (or compile, the first time on a machine), torch
            # and Embree set themselves up on first use, which no pose should be charged with
            pose_record(capture.poses[0], viewpoints[0])
            _rest_record(rest, static_grid, model, capture.grid, *rest_rays[0], device)
            for repeat in range(repeats):
                poses = []
                for pose, view in zip(capture.poses, viewpoints):
                    record, check = pose_record(pose, view, check=repeat == 0)
                    poses.append(record)
                    checks += [check] if check is not None else []
                rest_views = [_rest_record(rest, static_grid, model, capture.grid, *rays,
                                           device) for rays in rest_rays]
                runs.append({"poses": poses, "rest": rest_views})
                if progress is not None:
                    progress(repeat + 1, repeats)
        sizes = _bytes(capture, model, baselines)
        thread_counts = {"setting": threads, "torch": torch.get_num_threads(),
                         "encoder": thread_use.encoder_threads(),
                         "walk_lanes": thread_use.walk_lanes(device, width * height),
                         **{baseline.name: baseline.threads for baseline in baselines}}
        packets = {"width": embree.width, "native": embree.native, "version": embree.version}
    finally:
        close_baselines(baselines, embree)
        torch.set_num_threads(torch_threads)
        thread_use.use_encoder_threads(None)
        thread_use.use_cores(None)
    network = _model_info(model, capture, checks)
    if network["speed_withheld"] is not None:
        for run in runs:
            for record in run["poses"]:
                for key in RENDER_KEYS:
                    record.pop(key, None)
                withhold(record)
    result = _summary(obj, capture, runs, checks, network, sizes, width, height, repeats)
    result.update(threads=thread_counts, embree=packets, kernels_s=kernels_s)
    if secondary is not None:
        size = capture.mesh.size
        result["secondary"] = secondary_summary(
            result, secondary, None if model is None else model.secondary_offset(size), size)
    return result


def torch_setting(threads):
    """Torch's threads at the thread setting ``threads``: the setting less the core the
    Warp encoder runs on beside the MLP (``threads.ENCODER_CORES``), at least one."""
    return max(1, threads - ENCODER_CORES)


def thread_settings(values):
    """The thread settings named by ``values`` ("1", "all" or a count), in order, each once;
    'all' is every core this process may use."""
    settings = []
    for value in values:
        count = (thread_use.machine_cores() if value == "all"
                 else int(value) if value.isdigit() else 0)
        if count < 1:
            raise VDNIFError(f"thread setting '{value}' must be a count of at least 1 or 'all'")
        settings += [] if count in settings else [count]
    return settings


def synchronize(device):
    """Waits for the work queued on Warp ``device`` and torch's current CUDA device, so that
    a clock read next counts it: CUDA runs kernels asynchronously (the CPU needs nothing)."""
    if device.startswith("cuda"):
        runtime.init().synchronize_device(device)
        torch.cuda.synchronize()


def _pose_record(obj, posed_object, baselines, model, pose, view, width, height, check,
                 secondary):
    """(seconds of every path for one pose, each side's own Blender evaluation included;
    with ``check`` also the passes to check them: the true reference, the baselines' hits
    and the prediction)."""
    capture = posed_object.capture
    geometry = posed_object.geometry(pose)          # read corners + refit: prepare_s
    origins, directions = orbit_rays(geometry.vertices.min(0), geometry.vertices.max(0),
                                     view, width, height)
    record = {}
    with posed(pose):
        for baseline in baselines:
            parts = baseline.rebuild(obj)
            record.update({f"{baseline.name}_{part}": s for part, s in parts.items()})
            record[f"{baseline.name}_pose_s"] = sum(parts.values())
        deformer = posed_object.deformer
        record["neural_evaluate_s"] = 0.0 if deformer is None else evaluation_s(deformer.evaluated)
    record["neural_prepare_s"] = geometry.prepare_s
    record["neural_pose_s"] = record["neural_evaluate_s"] + geometry.prepare_s
    casts = {}
    for baseline in baselines:
        start = time.perf_counter()
        casts[baseline.name] = baseline.cast(origins, directions)
        record[f"{baseline.name}_cast_s"] = time.perf_counter() - start
        record[f"{baseline.name}_hits"] = int((casts[baseline.name][0] >= 0).sum())
    predicted = None
    if model is not None:
        synchronize(posed_object.device)
        start = time.perf_counter()
        predicted, stats = neural_passes(model.network, capture.grid, model.albedo_table,
                                         geometry.cells, origins, directions, model.device)
        synchronize(posed_object.device)
        record["neural_render_s"] = time.perf_counter() - start
        record.update(neural_walk_s=stats["walk_s"], neural_network_s=stats["network_s"],
                      neural_segments=stats["segments"], neural_hits=int(predicted.hit.sum()))
    if secondary is not None:
        record.update(secondary_record(
            baselines, casts, model, predicted, geometry.cells, capture.grid,
            capture.mesh.triangles, (origins, directions), capture.mesh.size, secondary,
            lambda: synchronize(posed_object.device)))
    if not check:
        return record, None
    true = true_reference(capture.mesh, geometry.mesh_caster(capture.mesh.triangles),
                          origins, directions)
    return record, {"true": true, "casts": casts, "predicted": predicted}


def _rest_record(rest, static_grid, model, grid, origins, directions, device):
    """Deformed walk vs static DDA walk of the same rest-pose rays, and with a model the
    network over every walked segment (the same segments for both walks)."""
    synchronize(device)
    start = time.perf_counter()
    deformed = traverse(rest.cells, origins, directions, lanes=1)   # as the DDA: one launch
    synchronize(device)
    deformed_walk_s = time.perf_counter() - start
    start = time.perf_counter()
    static = static_grid.traverse(origins, directions)
    synchronize(device)
    static_walk_s = time.perf_counter() - start
    match = (len(deformed) == len(static) and np.array_equal(deformed.ray, static.ray)
             and np.array_equal(deformed.cell, static.cell))
    record = {"deformed_walk_s": deformed_walk_s, "static_walk_s": static_walk_s,
              "walk_segments": len(static), "deformed_walk_segments": len(deformed),
              "segments_match": bool(match)}
    if model is not None:
        start = time.perf_counter()
        if len(static):
            predict_segments(model.network, grid, static, model.device)
        synchronize(device)
        record["all_segments_network_s"] = time.perf_counter() - start
    return record


def _model_info(model, capture, checks):
    """The network's description: the model, its hit IoU against the true reference on the
    checked views, and why speeds are withheld (None when they are not)."""
    if model is None:
        return {"trained": False, "model": None, "variant": None, "hit_iou": None,
                "speed_withheld": NO_MODEL}
    predicted = Passes.concatenate([check["predicted"] for check in checks])
    true = Passes.concatenate([check["true"] for check in checks])
    vs_true = compare(predicted, true, capture.mesh.size)
    return {"trained": True, "model": str(model.path), "variant": model.variant,
            "device": str(model.device), "precision": model.network.precision,
            "hit_iou": vs_true["hit_iou"],
            "false_negative_rate": vs_true["false_negative_rate"],
            "false_positive_rate": vs_true["false_positive_rate"],
            "speed_withheld": speed_withheld(vs_true["hit_iou"])}


def _summary(obj, capture, runs, checks, network, sizes, width, height, repeats):
    mesh = capture.mesh
    keys = dict.fromkeys(key for run in runs for record in run["poses"] + run["rest"]
                         for key in record)
    medians = {key: statistics.median(_mean(run, key) for run in runs) for key in keys
               if key.endswith(("_s", "segments", "hits", "rays"))}
    rays = width * height
    speeds = {name: _median_or_none([_per_second(rays, _mean(run, key)) for run in runs])
              for name, key in (("neural", "neural_render_s"),
                                *((b, f"{b}_cast_s") for b in BASELINES))}
    ratio_runs = {name: [_ratio(run, name) for run in runs] for name in RATIOS}
    return {
        "object": obj.name, "triangles": int(len(mesh.triangles)),
        "vertices": int(len(mesh.vertices)), "mode": capture.mode,
        "resolution": capture.grid.resolution,
        "occupied_voxels": int(len(capture.grid.cells)), "poses": len(capture.poses),
        "width": width, "height": height, "rays": rays, "repeats": repeats,
        "network": network, "speed_withheld": network["speed_withheld"],
        "median": medians, "rays_per_s": speeds,
        "ratios": {name: _median_or_none(values) for name, values in ratio_runs.items()},
        "ratio_runs": ratio_runs,
        "agreement": _agreement(checks, mesh.size),
        "segments_match": all(v["segments_match"] for run in runs for v in run["rest"]),
        "bytes": sizes, "runs": runs,
    }


def _agreement(checks, object_size):
    """Per baseline, against the true reference over the checked views: rays whose hit
    differs, rays both hit, and the largest distance difference there in object units."""
    true_hit = np.concatenate([c["true"].hit for c in checks])
    true_distance = np.concatenate([c["true"].distance for c in checks])
    result = {}
    for name in BASELINES:
        hit = np.concatenate([c["casts"][name][0] >= 0 for c in checks])
        distance = np.concatenate([c["casts"][name][1] for c in checks])
        both = hit & true_hit
        result[name] = {
            "rays": int(len(hit)), "differing_hits": int((hit != true_hit).sum()),
            "both_hit": int(both.sum()),
            "max_distance_difference": float(np.abs(distance[both] - true_distance[both]).max()
                                             / object_size) if both.any() else None}
    return result


def _mean(run, key):
    records = [r for r in run["poses"] + run["rest"] if key in r]
    return statistics.fmean(record[key] for record in records) if records else None


def _per_second(count, seconds):
    return None if seconds is None else count / seconds


def _median_or_none(values):
    return None if any(v is None for v in values) else statistics.median(values)


def _ratios():
    """name: (numerator keys, denominator keys), sums of per-pose / per-view means."""
    ratios = {}
    for b in BASELINES:
        ratios[f"prepare_neural_over_{b}"] = (("neural_pose_s",), (f"{b}_pose_s",))
        ratios[f"render_neural_over_{b}"] = (("neural_render_s",), (f"{b}_cast_s",))
        ratios[f"pose_neural_over_{b}"] = (("neural_pose_s", "neural_render_s"),
                                           (f"{b}_pose_s", f"{b}_cast_s"))
    ratios["walk_deformed_over_static"] = (("deformed_walk_s",), ("static_walk_s",))
    ratios["walk_and_network_deformed_over_static"] = (
        ("deformed_walk_s", "all_segments_network_s"),
        ("static_walk_s", "all_segments_network_s"))
    return ratios


RATIOS = _ratios()


def _ratio(run, name):
    """A ratio of one repeat, or None when a side was not run or is withheld."""
    numerator, denominator = (tuple(_mean(run, key) for key in keys) for keys in RATIOS[name])
    if None in numerator or None in denominator:
        return None
    return sum(numerator) / sum(denominator)


def _bytes(capture, model, baselines):
    """Model bytes against mesh (float32 vertices, int32 triangles) + each baseline's BVH
    bytes (``baselines``: how each is found)."""
    mesh = capture.mesh
    mesh_bytes = 12 * len(mesh.vertices) + 12 * len(mesh.triangles)
    if model is not None:
        model_bytes, source = pathlib.Path(model.path).stat().st_size, "model file"
    else:
        config = dataclasses.replace(NetworkConfig(),
                                     heads=Heads.from_header(mesh.heads()))
        with torch.random.fork_rng():
            torch.manual_seed(0)
            network = IntersectionNetwork(config)
        buffer = io.BytesIO()
        torch.save(network.state_dict(), buffer)
        model_bytes = len(buffer.getvalue())
        source = "serialized state_dict of the paper's configuration (no model file)"
    bvh = {baseline.name: baseline.bvh_bytes() for baseline in baselines}
    return {"model": model_bytes, "model_source": source, "mesh": mesh_bytes, "bvh": bvh,
            "bvh_source": {baseline.name: baseline.bytes_source for baseline in baselines},
            "model_over_mesh_and_bvh": {name: model_bytes / (mesh_bytes + size)
                                        for name, size in bvh.items()}}


def machine(load_before, device):
    """The machine and thread settings of a run on torch ``device``, for the report
    (``load_before``: the load average when it started)."""
    cpu, vector = runtime.cpu_description()
    warp = runtime.init()
    return {"cpu": cpu, "vector": vector, "cores": thread_use.machine_cores(),
            "load_before": load_before,
            "load_after": os.getloadavg()[0],
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "torch": torch.__version__, "torch_threads": torch.get_num_threads(),
            "warp": warp.__version__, "warp_device": runtime.device(device),
            "embreex": importlib.metadata.version("embreex"),
            "blender": bpy.app.version_string}


def sample_counts(settings):
    """The AO samples per pixel a run times: 1 and the settings' N (once where N is 1)."""
    return sorted({1, settings.samples})


def key(name, samples, what):
    """The record key of path ``name``'s secondary ``what`` ("s", "ao_rays", "shadow_rays",
    "ao_mean", "lit_share") at ``samples`` AO samples per pixel."""
    return f"{name}_secondary{samples}_{what}"


def secondary_record(baselines, casts, model, predicted, cells, grid, triangles, rays,
                     object_size, settings, sync):
    """Record entries of one pose: per path of ``SECONDARY_PATHS`` that ran and per AO
    sample count, the seconds of its secondary rays, the AO and shadow rays it cast, its
    mean AO and its lit share over its hits. ``casts`` {baseline: (index, t)} are the
    classical primary casts of ``rays`` (origins, directions), ``predicted`` the network's
    primary passes (None without ``model``) over ``grid``; ``sync`` waits for queued device
    work."""
    paths = {}
    for baseline in baselines:
        if baseline.name in SECONDARY_BASELINES:
            paths[baseline.name] = (lambda b=baseline: (
                mesh_primary(b.vertices, triangles, *casts[b.name]), exact_occluded(b)), None)
    if model is not None:
        # The network's hits start their rays off by its own error, as its passes do.
        offset = model.secondary_offset(object_size)
        network = neural_occluded(model.network, grid, model.albedo_table, cells, offset,
                                  model.device)
        paths["neural"] = (lambda: (predicted, network), offset)
    record = {}
    for samples in sample_counts(settings):
        at = dataclasses.replace(settings, samples=samples)
        for name, (prepare, offset) in paths.items():
            sync()
            start = time.perf_counter()
            # A name of its own: the neural path's lambda reads ``network`` when called, so
            # rebinding that name here would hand it a baseline's occluder.
            primary, answers = prepare()
            passes = secondary_passes(primary, *rays, answers, object_size, at, offset)
            sync()
            seconds = time.perf_counter() - start
            # one AO ray per sample of each hit, one shadow ray from each hit facing the light
            hits = int(passes.hit.sum())
            ao_rays, shadow_rays = hits * samples, int(passes.facing.sum())
            record.update({
                key(name, samples, "s"): seconds, key(name, samples, "ao_rays"): ao_rays,
                key(name, samples, "shadow_rays"): shadow_rays,
                key(name, samples, "ao_mean"): float(passes.ao[passes.hit].mean())
                if hits else None,
                key(name, samples, "lit_share"): float(passes.lit[passes.hit].mean())
                if hits else None})
    return record


def withhold(record):
    """Drops the neural path's secondary entries from a pose ``record`` (its speeds are
    withheld)."""
    for name in [k for k in record if k.startswith(NEURAL_PREFIX)]:
        del record[name]


def secondary_summary(result, settings, network_offset=None, object_size=1.0):
    """The secondary table of a ``compare_paths`` ``result`` timed with ``settings`` (the
    network's hits started ``network_offset`` local units off, when it ran, an object unit
    ``object_size`` local ones): per
    path and AO sample count, the rays per pose, their milliseconds and rays per second,
    the pose total, the mean AO and lit share (medians over repeats; None where not run
    or withheld), and per classical path where the cheaper side changes."""
    counts = sample_counts(settings)
    paths = {}
    for name in SECONDARY_PATHS:
        paths[name] = {str(samples): _figures(result, name, samples) for samples in counts}
    return {"settings": dict(settings.describe(network_offset, object_size), samples=counts),
            "paths": paths, "skipped": SKIPPED,
            "trade": {b: trade_point(paths["neural"], paths[b], counts)
                      for b in SECONDARY_BASELINES}}


def _figures(result, name, samples):
    runs = [[r for r in run["poses"] if key(name, samples, "s") in r]
            for run in result["runs"]]
    if not all(runs):
        return {"rays": None, "ao_rays": None, "shadow_rays": None, "ms": None,
                "rays_per_s": None, "pose_total_ms": None, "ao_mean": None, "lit_share": None}

    def median(what):
        values = [statistics.fmean(r[key(name, samples, what)] for r in poses)
                  for poses in runs if all(r[key(name, samples, what)] is not None
                                           for r in poses)]
        return statistics.median(values) if values else None

    rays = [[r[key(name, samples, "ao_rays")] + r[key(name, samples, "shadow_rays")]
             for r in poses] for poses in runs]
    rates = [statistics.fmean(count) / statistics.fmean(r[key(name, samples, "s")]
                                                        for r in poses)
             for count, poses in zip(rays, runs)]
    ms = 1e3 * median("s")
    primary = pose_total(result, name)
    return {"rays": statistics.median(statistics.fmean(count) for count in rays),
            "ao_rays": median("ao_rays"), "shadow_rays": median("shadow_rays"), "ms": ms,
            "rays_per_s": statistics.median(rates),
            "pose_total_ms": None if primary is None else primary + ms,
            "ao_mean": median("ao_mean"), "lit_share": median("lit_share")}


def trade_point(neural, classical, counts):
    """Where the neural pose total meets a classical one, both taken as linear in the AO
    samples through the two measured counts: "samples" where they meet between them (None
    otherwise), "beyond" where the lines meet past N (an extrapolation, None otherwise)."""
    totals = [(neural[str(s)]["pose_total_ms"], classical[str(s)]["pose_total_ms"])
              for s in counts]
    if any(n is None for n, _ in totals):
        return {"samples": None, "beyond": None, "text": "n/a (no neural speed)"}
    ratios = ", ".join(f"{n / c:.3g} at {s}" for (n, c), s in zip(totals, counts))
    differences = [n - c for n, c in totals]
    meet = None
    if len(counts) == 2 and differences[0] != differences[1]:
        low, high = counts
        meet = low + (high - low) * differences[0] / (differences[0] - differences[1])
    if meet is not None and counts[0] < meet < counts[-1]:
        way = "from" if differences[0] > 0 else "up to"
        return {"samples": meet, "beyond": None,
                "text": f"neural cheaper {way} {meet:.3g} AO samples (neural / "
                        f"classical {ratios})"}
    side = "neural" if differences[-1] < 0 else "classical"
    beyond = meet if meet is not None and meet >= counts[-1] else None
    text = (f"{side} cheaper at {' and '.join(map(str, counts))} AO samples (neural / "
            f"classical {ratios})")
    if beyond is not None:
        text += f"; the lines meet at {beyond:.3g} AO samples (extrapolated)"
    return {"samples": None, "beyond": beyond, "text": text}


SIZES = {   # full: the recipe; quick: a tiny training, for tests (its models predict no hits)
    "full": dict(resolution=None, poses=RECIPE.poses, rays_per_pose=RECIPE.rays_per_pose,
                 overrides={}),
    "quick": dict(resolution=8, poses=2, rays_per_pose=64,
                  overrides=dict(steps=20, batch_size=256, log2_table_size=10)),
}


def model_file(folder, scene):
    """Where the model trained for ``scene`` lives in ``folder``."""
    return pathlib.Path(folder) / f"{scene}.vdnif"


def recipe_model(scene, folder, seed=0, device="auto", quick=False, progress=None):
    """The model of side-by-side scene ``scene`` in ``folder``, trained first (by the recipe,
    training poses of ``seed``) where the file is missing; returns its path."""
    path = model_file(folder, scene)
    if path.exists():
        print(f"side-by-side: '{scene}' uses the model {path} (trained before)",
              file=sys.stderr)
        return path
    size = SIZES["quick" if quick else "full"]
    obj = load_side_by_side_scene(scene)
    resolution = size["resolution"] or recipe_resolution(obj)
    captured = training_capture(obj, resolution, PoseSpec(count=size["poses"], seed=seed),
                                say=lambda line: print(f"side-by-side: '{scene}': {line}",
                                                       file=sys.stderr))
    variant, _ = choose_variant(None, captured.mode == "static")
    path.parent.mkdir(parents=True, exist_ok=True)
    print(f"side-by-side: training {variant} on '{obj.name}' ({scene}) by the "
          f"{'quick size' if quick else 'recipe'} into {path}", file=sys.stderr)
    overrides = dict(size["overrides"], device=device, seed=seed)
    with tempfile.TemporaryDirectory(prefix="vdnif-data-") as scratch:
        train_variant(obj, captured, variant, scratch, size["rays_per_pose"], path, overrides,
                      seed, progress=progress)
    return path
