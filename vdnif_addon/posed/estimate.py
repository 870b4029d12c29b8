"""What a run from scratch costs before it starts: the dataset's size on disk and the time of
generating it and of training, from rates measured on a small sample of the same work.

The sample walks ``PROBE_RAYS`` rays through each of the first ``PROBE_POSES`` poses with
the real walk and ground truth and writes them as a real shard, then times
``PROBE_STEPS`` training steps of the real network at the real batch size on it. The
estimate scales those rates: bytes per segment x the expected segments (rays x segments
per ray), seconds per pose and per ray, samples per second. Touches no Blender data (its
poses come through a PoseSource, like ``generate_dataset``'s).
"""

import dataclasses
import pathlib
import shutil
import statistics

from ..training.fit import fit_model
from ..worker import duration
from .generate import generate_dataset

PROBE_POSES = 2
"""Poses of the sample: two, so that training holds one out as it does on a full dataset."""
PROBE_RAYS = 2048
"""Rays walked per sample pose: enough for a stable count of segments per ray."""
WARM_RAYS = 64
"""Rays of the walk that loads the kernels first (their first load is no rate of the run)."""
PROBE_STEPS = 6
"""Training steps timed; the rate is the median over the second half (the first warm up)."""


def probe_poses(captured):
    """The poses the sample reads, in order: the first one for the warm-up, then the
    sample's (a PoseSource must deliver exactly these)."""
    return [pose for pose in captured.poses[:1] + captured.poses[:PROBE_POSES]
            if not pose.get("rest")]


def measure(source, captured, variant, overrides, scratch, seed=0, rays_per_pose=PROBE_RAYS,
            **mix):
    """Rates of the sample of ``captured`` (the variant's capture, ``steps.variant_capture``)
    written under the folder ``scratch`` (emptied first, removed after): segments per ray,
    bytes per segment, seconds per pose and per ray, the rest surface's seconds, the write
    speed and training samples per second (``overrides``: the NetworkConfig / TrainConfig
    fields of the run, ``batch_size`` among them; ``variant`` None: the dataset alone, no
    training timed). The sample walks at most ``rays_per_pose`` rays per pose, with the ray
    ``mix`` of ``generate_dataset`` (the recipe's unless given)."""
    scratch = pathlib.Path(scratch)
    shutil.rmtree(scratch, ignore_errors=True)
    records = []
    try:
        generate_dataset(source, dataclasses.replace(captured, poses=captured.poses[:1]),
                         scratch / "warm", WARM_RAYS, seed=seed, **mix)
        sample = dataclasses.replace(captured, poses=captured.poses[:PROBE_POSES])
        header = generate_dataset(source, sample, scratch / "data",
                                  min(PROBE_RAYS, rays_per_pose), seed=seed, **mix)
        written = sum(path.stat().st_size for path in (scratch / "data").iterdir())
        if variant is not None:
            fit_model(scratch / "data", variant, scratch / "sample.vdnif",
                      dict(overrides, steps=PROBE_STEPS, log_interval=1),
                      progress=records.append)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    timings, counts = header.timings, header.counts
    return {
        "segments_per_ray": counts.segments / counts.rays,
        "bytes_per_segment": written / counts.segments,
        "pose_s": (timings["prepare_s"] + timings["evaluate_s"]) / len(sample.poses),
        "ray_s": sum(timings[name] for name in ("rays_s", "walk_s", "ground_truth_s",
                                                 "records_s")) / counts.rays,
        "rest_surface_s": timings["rest_surface_s"],
        "write_bytes_per_s": written / max(timings["write_s"], 1e-6),
        "samples_per_s": statistics.median(record["samples_per_s"]
                                           for record in records[PROBE_STEPS // 2:])
        if records else None,
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


def estimate(rates, poses, rays_per_pose, steps, batch_size):
    """The run's figures from ``measure``'s rates: the dataset's (``dataset_estimate``) and
    ``steps`` of ``batch_size`` samples of training."""
    return {**dataset_estimate(rates, poses, rays_per_pose),
            "train_s": steps * batch_size / rates["samples_per_s"], "rates": rates}


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
