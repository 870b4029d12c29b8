"""The UI's long operations as WorkerJobs (``worker``): generating a dataset, evaluating,
rendering a range of frames and measuring the estimate of a run, each with progress and
cancel while Blender stays responsive.

Each job's poses are read from Blender on the main thread (``pose_job``'s reads: Blender's
data may be read nowhere else) and computed on in the worker, through the same functions the
batch commands run with the live object (``generate_dataset``, ``evaluate_file``,
``render_frames``): in background mode ``WorkerJob.run`` passes those functions a live
``PoseReader`` instead of the feed, so both paths are one.
"""

import os
import pathlib
import shutil
import threading

from ..model.variants import variant_config
from ..posed import estimate as estimates
from ..posed.animation import frame_pose, render_frames
from ..posed.generate import generate_dataset
from ..posed.pose_source import PoseFeed
from ..posed.render import camera_view, load_scene_model
from ..settings import DEFAULT_PRECISION
from ..training.dataset import MANIFEST
from ..worker import DirectCalls, MainCalls, WorkerJob
from .pose_reader import PoseReader
from .steps import evaluate_file, variant_capture

SHARD_PATTERN = "shard-*.*"
SHARD_SUFFIXES = (".json", ".npz")


def pose_job(title, unit, obj, captured, poses, work, view=None, on_output=None, total=None):
    """A WorkerJob whose ``work(source, progress, deliver)`` reads ``poses`` of ``obj``
    (``captured``), in this order, through ``source``: a ``PoseReader`` (with the camera
    ``view`` function read in each pose) in ``run``, a ``PoseFeed`` that the job's reads fill
    on the main thread in ``start``."""
    cancel = threading.Event()
    feed = PoseFeed(obj.name, cancel, host=PoseReader.host)

    def reads():
        # Runs on Blender's main thread, one pose per step, between the UI's events.
        reader = PoseReader(obj, captured, view)
        try:
            for pose in poses:
                while feed.feed.full():
                    yield False
                feed.feed.put(reader.read(pose))
                yield True
        finally:
            reader.close()

    return WorkerJob(title, total or len(poses), unit, work,
                     live=lambda: PoseReader(obj, captured, view), feed=feed, reads=reads,
                     on_output=on_output, cancel=cancel)


def reads_of(captured):
    """The poses of ``captured`` that are read from Blender (the rest pose is not)."""
    return [pose for pose in captured.poses if not pose.get("rest")]


def dataset_job(obj, captured, variant, folder, rays_per_pose, seed=0):
    """Generates the dataset of ``variant`` (``steps.variant_dataset``) into ``folder``. The
    shards are written beside it first and replace the folder's shards only once complete:
    a cancelled or failed run leaves the previous dataset as it was. Result: the header."""
    captured, rays_per_pose = variant_capture(captured, variant, rays_per_pose)
    folder = pathlib.Path(folder)

    def work(source, progress, _deliver):
        partial = folder.with_name(f".{folder.name}.partial")
        shutil.rmtree(partial, ignore_errors=True)
        try:
            header = generate_dataset(source, captured, partial, rays_per_pose, seed=seed,
                                      progress=progress)
            replace_shards(partial, folder)
        finally:
            shutil.rmtree(partial, ignore_errors=True)
        counts = header.counts
        return f"{counts.segments} segments of {counts.rays} rays", header

    return pose_job("dataset", "poses", obj, captured, reads_of(captured), work,
                    total=len(captured.poses))


def dataset_files(folder):
    """The files of a dataset in ``folder``: its shards and its manifest (nothing else)."""
    folder = pathlib.Path(folder)
    return [path for path in [*folder.glob(SHARD_PATTERN), folder / MANIFEST]
            if path.suffix in SHARD_SUFFIXES or (path.name == MANIFEST and path.exists())]


def replace_shards(source, folder):
    """Replaces the dataset in ``folder`` (shards and manifest: the new one may be of
    another grid) with the one in ``source`` (moved)."""
    folder.mkdir(parents=True, exist_ok=True)
    for path in dataset_files(folder):
        path.unlink()
    for path in dataset_files(source):
        os.replace(path, folder / path.name)


def evaluation_job(obj, captured, model_path, width, height, device, loaded=None,
                   secondary=None, precision=DEFAULT_PRECISION):
    """Evaluates the model file on the evaluation poses of ``captured``
    (``steps.evaluate_file``; the AO and shadow passes too with ``secondary``, their
    ``SecondarySettings``; the MLPs in ``precision``). Result: the report."""

    def work(source, progress, _deliver):
        report, _ = evaluate_file(source, captured, model_path, width, height, device,
                                  progress=progress, loaded=loaded, secondary=secondary,
                                  precision=precision)
        return f"{report['poses']} poses evaluated", report

    return pose_job("evaluation", "poses", obj, captured, reads_of(captured), work)


def frames_job(obj, captured, model_path, frames, width, height, device, on_frame,
               camera=None, view=None, references=False, loaded=None, secondary=None,
               precision=DEFAULT_PRECISION):
    """Renders ``frames`` (``animation.render_frames``) through ``camera`` (read in each
    frame), else the fixed ``view``, else an orbit viewpoint; the AO and shadow passes too
    with ``secondary`` (their ``SecondarySettings`` for every frame, read before the job:
    Blender's data are read on the main thread only); ``on_frame(frame, result)`` runs on the
    main thread for each (it writes the images). Result: the per-frame figures."""
    read_view = None if camera is None else (lambda: camera_view(camera, width, height))

    def work(source, progress, deliver):
        model = load_scene_model(model_path, captured, device, loaded, precision)
        figures = render_frames(source, captured, model, frames, width, height, view,
                                references, each=lambda frame, result: deliver(
                                    (frame, result)), progress=progress,
                                secondary=None if secondary is None else (
                                    lambda _frame: secondary))
        return f"{len(frames)} frames rendered", figures

    return pose_job("render", "frames", obj, captured, [frame_pose(f) for f in frames], work,
                    view=read_view, on_output=lambda item: on_frame(*item))


def estimate_job(obj, captured, variant, rays_per_pose, overrides, scratch, seed=0):
    """Measures the estimate of generating the dataset of ``variant`` and training with
    ``overrides`` (``estimate``). Result: the estimate's figures."""
    captured, rays_per_pose = variant_capture(captured, variant, rays_per_pose)

    def work(source, progress, _deliver):
        rates = estimates.measure(source, captured, variant, overrides, scratch, seed)
        progress(1, 1)
        figures = estimates.estimate(rates, len(captured.poses), rays_per_pose,
                                     variant_config(variant, **overrides).train)
        return estimates.describe(figures), figures

    return pose_job("estimate", "samples", obj, captured, estimates.probe_poses(captured),
                    work, total=1)


def suggestion_job(obj, spec, target, floor, candidates):
    """Suggests the voxel resolution (``resolution.suggest_resolution``; ``floor``: the
    object's ``resolution.Floor``, read on the main thread): each candidate's capture and
    poses are read on the main thread when the worker asks for them. Result: the
    Suggestion."""
    from .resolution import considered, suggest_resolution

    cancel = threading.Event()
    tried = considered(candidates, floor.textured)

    def work(calls, progress, _deliver):
        done = []
        suggested = suggest_resolution(
            obj, spec, target, candidates, floor=floor, calls=calls,
            progress=lambda resolution, _: done.append(resolution) or progress(
                len(done), len(tried)))
        return f"suggested {suggested.resolution}", suggested

    return WorkerJob("suggestion", len(tried), "resolutions", work, live=DirectCalls,
                     feed=MainCalls(cancel), cancel=cancel)


def follow_job(obj, resolution, spec):
    """Chooses how the corners of ``obj`` follow it in training at ``resolution`` on the
    poses of ``spec`` (``follow_choice.choose_follow``): each capture and pose is read on
    the main thread when the worker asks for it. Result: the FollowChoice."""
    from .follow_choice import choose_follow

    cancel = threading.Event()

    def work(calls, progress, _deliver):
        choice = choose_follow(obj, resolution, spec, calls=calls, progress=progress)
        return choice.describe(), choice

    return WorkerJob("corners", 2, "ways", work, live=DirectCalls, feed=MainCalls(cancel),
                     cancel=cancel)
