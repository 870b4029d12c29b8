"""What a run from scratch costs before it starts: the dataset's size on disk and the time of
generating it and of training, from rates measured on a small sample of the same work.

The sample walks ``PROBE_RAYS`` rays through each of the first ``PROBE_POSES`` poses with
the real walk and ground truth and writes them as a real shard (and a quarter of the rays,
to tell the cost per pose from the cost per ray; each size twice, the faster counting),
then trains the real
network on it at the real batch size for ``PROBE_STEPS`` steps, as the training job does
(its torch threads, a validation every ``PROBE_WINDOW`` steps rather than after each,
where the next batch would be gathered unseen), timing the windows after the first (which
warms up) and the work around the steps: reading and splitting the data, validating, the
held-out pass and calibration. The estimate scales those rates to the run: bytes per
segment x the expected segments (rays x segments per ray), seconds per pose and per ray,
samples per second, seconds per segment read and split and per held-out row validated,
plus the seconds of saving the model. Touches no Blender data (its poses come through a
PoseSource, like ``generate_dataset``'s).
"""

import dataclasses
import pathlib
import shutil

from ..threads import use_threads
from ..training.data import held_out_count
from ..training.fit import fit_model
from ..worker import duration
from .generate import generate_dataset

PROBE_POSES = 2
"""Poses of the sample: two, so that training holds one out as it does on a full dataset."""
PROBE_RAYS = 8192
"""Rays walked per sample pose: enough for a stable count of segments per ray, and training
rows of many distinct rays (a sample smaller than a batch trains on rows and table entries
that stay in the cache, faster than a full dataset does)."""
WARM_RAYS = 64
"""Rays of the walk that loads the kernels first (their first load is no rate of the run)."""
PROBE_STEPS, PROBE_WINDOW = 18, 6
"""Training steps timed, in windows of PROBE_WINDOW steps (a validation after each); the
rate is over the windows after the first, which warms up (four steps were not enough)."""


SMALL_SHARE = 4
"""The sample walks its poses at two sizes, with all its rays and with 1/SMALL_SHARE of them: the
difference is the cost per ray, the rest the cost per pose (the walk's waves cost about a
tenth of a second a pose whatever the rays, so one size alone overstates the rays' cost
of a run with more rays a pose than the sample)."""
RAY_TIMINGS = ("rays_s", "walk_s", "ground_truth_s", "records_s")
REPEATS = 2
"""Times each size of the sample is walked, alternating; the fastest counts (a machine shared
with other work slows a second-long walk by up to 3x, never speeds it up)."""


def probe_poses(captured):
    """The poses the sample reads, in order: the first one for the warm-up, then the
    sample's, 2 x REPEATS times (a PoseSource must deliver exactly these)."""
    sample = captured.poses[:PROBE_POSES]
    return [pose for pose in captured.poses[:1] + sample * (2 * REPEATS)
            if not pose.get("rest")]


def measure(source, captured, variant, overrides, scratch, seed=0, rays_per_pose=PROBE_RAYS,
            **mix):
    """Rates of the sample of ``captured`` (the variant's capture, ``steps.variant_capture``)
    written under the folder ``scratch`` (emptied first, removed after): segments per ray,
    bytes per segment, seconds per pose and per ray, the rest surface's seconds, the write
    speed and the training's rates (``_probe_training``; ``overrides``: the NetworkConfig /
    TrainConfig fields of the run; ``variant`` None: the dataset alone, no training timed).
    The sample walks at most ``rays_per_pose`` rays per pose, with the ray ``mix`` of
    ``generate_dataset`` (the recipe's unless given)."""
    scratch = pathlib.Path(scratch)
    shutil.rmtree(scratch, ignore_errors=True)
    try:
        generate_dataset(source, dataclasses.replace(captured, poses=captured.poses[:1]),
                         scratch / "warm", WARM_RAYS, seed=seed, **mix)
        sample = dataclasses.replace(captured, poses=captured.poses[:PROBE_POSES])
        rays = min(PROBE_RAYS, rays_per_pose)
        walks = {"small": [], "data": []}
        for repeat in range(REPEATS):
            for name, count in (("small", max(rays // SMALL_SHARE, 1)), ("data", rays)):
                folder = scratch / (name if repeat == REPEATS - 1 else f"{name}-{repeat}")
                walks[name].append(generate_dataset(source, sample, folder, count, seed=seed,
                                                    **mix))
        small, header = (min(walks[name], key=_walked) for name in ("small", "data"))
        written = sum(path.stat().st_size for path in (scratch / "data").iterdir())
        training = (_probe_training(scratch / "data", variant, overrides, header.counts.segments)
                    if variant is not None else {})
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    timings, counts = header.timings, header.counts
    ray_s, pose_walk_s = _split_ray_cost(small, header)
    return {
        "segments_per_ray": counts.segments / counts.rays,
        "bytes_per_segment": written / counts.segments,
        "pose_s": (timings["prepare_s"] + timings["evaluate_s"]) / len(sample.poses)
        + pose_walk_s,
        "ray_s": ray_s,
        "rest_surface_s": timings["rest_surface_s"],
        "write_bytes_per_s": written / max(timings["write_s"], 1e-6),
        "samples_per_s": None, **training,
    }


def _walked(header):
    """The seconds a dataset's walk and what follows it took (RAY_TIMINGS)."""
    return sum(header.timings[name] for name in RAY_TIMINGS)


def _split_ray_cost(small, large):
    """(seconds per ray, seconds per pose) of the walk and what follows it, from the sample
    walked with few rays (``small``) and with all of them (``large``, DatasetHeaders of the
    same poses): the line through the two. A noisy machine can make the difference
    negative; the cost is then the large sample's per ray alone."""
    poses = len(large.poses)
    extra_rays = large.counts.rays - small.counts.rays
    ray_s = (_walked(large) - _walked(small)) / extra_rays if extra_rays > 0 else 0.0
    if ray_s <= 0.0:
        return _walked(large) / large.counts.rays, 0.0
    pose_s = max(_walked(large) - ray_s * large.counts.rays, 0.0) / poses
    return ray_s, pose_s


def _probe_training(data, variant, overrides, segments):
    """The training rates of the sample dataset ``data`` of ``segments`` segments: samples
    per second after the warm-up, seconds per segment read and split, per validated row,
    per held-out row of the last pass, and the seconds of saving the model."""
    records = []
    use_threads()                         # the training job's threads
    result, _ = fit_model(data, variant, data.parent / "sample.vdnif",
                          dict(overrides, steps=PROBE_STEPS, log_interval=PROBE_WINDOW,
                               stop_patience=0), progress=records.append)
    timings = result.timings
    warm = records[1:]                    # equal windows: the rate over them all
    rate = len(warm) / sum(1 / record["samples_per_s"] for record in warm)
    return {
        "samples_per_s": rate,
        "prepare_s_per_segment": (timings["read_s"] + timings["split_s"]) / segments,
        "validation_s_per_row": timings["validation_s"] / max(
            timings["validations"] * timings["probe_rows"], 1),
        "final_s_per_row": timings["final_s"] / max(timings["held_out_rows"], 1),
        # Saving the model. Not the rest of the sample's wall time: that is what the first
        # training of a process pays once (loading kernels and torch's parts, which the
        # sample has done for the run after it), and the first window's warm-up, which a
        # run pays in its own steps.
        "fixed_s": timings["save_s"],
    }


def dataset_estimate(rates, poses, rays_per_pose):
    """The dataset's figures from ``measure``'s rates: ``poses`` walked with
    ``rays_per_pose`` rays each (the variant's capture): segments, bytes on disk, seconds."""
    rays = poses * rays_per_pose
    segments = rays * rates["segments_per_ray"]
    size = segments * rates["bytes_per_segment"]
    dataset_s = (rates["rest_surface_s"] + poses * rates["pose_s"] + rays * rates["ray_s"]
                 + size / rates["write_bytes_per_s"])
    return {"segments": round(segments), "bytes": round(size), "dataset_s": dataset_s}


def estimate(rates, poses, rays_per_pose, config):
    """The run's figures from ``measure``'s rates: the dataset's (``dataset_estimate``) and
    the training's by ``config`` (the run's TrainConfig): its steps of batch_size samples,
    reading and splitting every segment, a validation every log_interval steps, the pass
    over the held-out poses' rows, and the sample's fixed cost; at most, where the stopping
    rule ends training sooner."""
    figures = dataset_estimate(rates, poses, rays_per_pose)
    segments = figures["segments"]
    held_out = (segments * held_out_count(poses, config.val_fraction) / poses if poses > 1
                else segments * config.val_fraction)
    validations = -(-config.steps // config.log_interval)
    train_s = (rates["fixed_s"] + config.steps * config.batch_size / rates["samples_per_s"]
               + segments * rates["prepare_s_per_segment"]
               + validations * min(config.val_segments, held_out) * rates["validation_s_per_row"]
               + held_out * rates["final_s_per_row"])
    return {**figures, "train_s": train_s, "rates": rates}


def size_text(size):
    """``108 MB``: a byte count in words."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{size:.0f} bytes"


def describe(figures, dataset=True):
    """One line of an estimate: disk and time (with ``dataset`` False, training alone;
    without a training time, the dataset alone)."""
    parts = ([f"dataset about {size_text(figures['bytes'])} on disk and "
              f"{duration(figures['dataset_s'])} to walk"] if dataset else [])
    if figures.get("train_s") is not None:
        parts.append(f"training about {duration(figures['train_s'])}")
    return ", ".join(parts)
