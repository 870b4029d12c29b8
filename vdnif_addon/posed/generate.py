"""Per-pose work over a captured object: training datasets and the two references."""

import dataclasses
import json
import platform
import time

import numpy as np

from ..geometry.attributes import sample_surface
from ..geometry.capture import ARMATURE_COPY
from ..inference.evaluation import metric_heads
from ..inference.metrics import compare, compare_secondary
from ..inference.secondary import (
    embedded_occluded,
    exact_occluded,
    exact_offset,
    secondary_views,
)
from ..kernels.cast import MeshCaster
from ..limits import check_image, check_range
from ..passes import Passes, SecondaryPasses
from ..settings import BOUNDS, RECIPE, calibration_view
from ..tracing.groundtruth import segment_targets
from ..tracing.rays import orbit_rays, orbit_viewpoints, training_rays
from ..tracing.references import embedded_reference, true_reference
from ..tracing.traverse import traverse
from ..training import dataset
from ..training.header import FORMAT, VERSION, DatasetHeader
from .geometry import PosedObject


def generate_dataset(obj, capture, out_dir, rays_per_pose, surface_fraction=None, seed=0,
                     pose_range=None, progress=None, grazing_fraction=None,
                     secondary_fraction=None):
    """Walks ``rays_per_pose`` training rays per pose of ``capture`` (``obj``: the mesh
    object or a PoseSource, see ``PosedObject``) (or of the slice
    ``pose_range`` = (start, stop)) and writes one shard; returns its DatasetHeader (its
    timings with the writing's). The ray mix
    (``rays.training_rays``) defaults to the recipe's (``settings.RECIPE``)."""
    check_range("rays per pose", rays_per_pose, *BOUNDS["rays_per_pose"])
    if surface_fraction is None:
        surface_fraction = RECIPE.surface_fraction
    if grazing_fraction is None:
        grazing_fraction = RECIPE.grazing_fraction
    if secondary_fraction is None:
        secondary_fraction = RECIPE.secondary_fraction
    # The training rays leave exact surface points, off by rounding only: the exact hits'
    # offset, not a network's
    offset = exact_offset(capture.mesh.size)
    start, stop = pose_range or (0, len(capture.poses))
    name = dataset.shard_name(start, stop)
    timings = dict(prepare_s=0.0, evaluate_s=0.0, rays_s=0.0, walk_s=0.0, ground_truth_s=0.0,
                   records_s=0.0)
    records, counts = [], dict(rays=0, segments=0, hits=0, truncated_rays=0)
    inverted = []
    side = calibration_view(rays_per_pose)
    with PosedObject(obj, capture) as posed_object:
        host = posed_object.source.host
        clock = time.perf_counter()
        rest_caster = posed_object.rest_caster
        timings["rest_surface_s"] = time.perf_counter() - clock
        for done, index in enumerate(range(start, stop), 1):
            geometry = posed_object.geometry(capture.poses[index])
            _pose_timings(timings, geometry)
            clock = time.perf_counter()
            rng = np.random.default_rng([seed, index])
            surface, triangle, _ = sample_surface(geometry.vertices, capture.mesh.triangles,
                                                  rays_per_pose, rng)
            corners = geometry.vertices[capture.mesh.triangles[triangle]]
            normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            origins, directions = training_rays(geometry.vertices.min(0),
                                                geometry.vertices.max(0), surface,
                                                rays_per_pose, surface_fraction, rng,
                                                normals, grazing_fraction,
                                                secondary_fraction=secondary_fraction,
                                                offset=offset)
            timings["rays_s"] += time.perf_counter() - clock
            walked = _walk_rows(geometry, capture, rest_caster, origins, directions, index, 0,
                                records, counts, timings)
            counts["truncated_rays"] += walked.truncated        # stopped by the walk's bounds
            counts["rays"] += rays_per_pose
            if side:            # numbered after the training rays (``settings``)
                clock = time.perf_counter()
                origins, directions = _calibration_rays(geometry, side, rng)
                timings["rays_s"] += time.perf_counter() - clock
                _walk_rows(geometry, capture, rest_caster, origins, directions, index,
                           rays_per_pose, records, counts, timings)
            inverted.append(geometry.inverted_cells())
            # the first pose's rows foretell the shard's (its size and memory): refused
            # then, not after the walk; later poses only past the limit itself
            dataset.check_shard_size(name, counts["segments"] * (stop - start) if done == 1
                                     else counts["segments"], memory=done == 1)
            if progress is not None:
                progress(done, stop - start)
    clock = time.perf_counter()
    merged = {name: np.concatenate([r[name] for r in records]) for name in dataset.ARRAYS}
    timings["records_s"] += time.perf_counter() - clock
    timings["total_s"] = sum(timings.values())
    header = DatasetHeader.from_dict({                   # the reader's checks, before writing
        "format": FORMAT, "version": VERSION,
        "object": capture.mesh.name, "mode": capture.mode, "object_size": capture.mesh.size,
        "grid": dataset.grid_header(capture.grid, capture.mesh).to_dict(),
        "voxel_size": capture.grid.voxel_size,
        "heads": capture.mesh.heads(), "albedo_table": capture.mesh.albedo_table().tolist(),
        # as the file holds them: JSON writes a lattice pose's integer point indices as text
        "poses": json.loads(json.dumps(capture.poses[start:stop])),
        "pose_range": [start, stop], "seed": seed,
        "rays_per_pose": rays_per_pose, "surface_fraction": surface_fraction,
        "grazing_fraction": grazing_fraction, "secondary_fraction": secondary_fraction,
        "inverted_cells": inverted, "counts": counts, "timings": timings,
        "view_rays": side * side,
        "versions": _versions(host), "segments": len(merged["pose"]),
        **({} if capture.corners_follow == ARMATURE_COPY
           else {"corners_follow": capture.corners_follow}),
    }, f"dataset header of shard '{name}'")
    clock = time.perf_counter()
    dataset.write_shard(out_dir, name, merged, header)
    write_s = time.perf_counter() - clock                # in the returned header only
    return dataclasses.replace(header, timings={**header.timings, "write_s": write_s})


def _walk_rows(geometry, capture, rest_caster, origins, directions, index, first_ray, records,
               counts, timings):
    """Walks the rays (``origins``, ``directions``) through pose ``index``'s cells
    (``geometry``) and appends their rows, with their targets, to ``records``, the rays
    numbered from ``first_ray``; adds their segments and hits to ``counts`` and their
    seconds to ``timings``. Returns the walk's Segments."""
    clock = time.perf_counter()
    segments = traverse(geometry.cells, origins, directions)
    timings["walk_s"] += time.perf_counter() - clock
    clock = time.perf_counter()
    targets = segment_targets(capture.mesh, rest_caster, segments)
    timings["ground_truth_s"] += time.perf_counter() - clock
    clock = time.perf_counter()
    records.append(dataset.segment_records(capture.grid, segments, targets, index))
    records[-1]["ray"] += first_ray
    timings["records_s"] += time.perf_counter() - clock
    counts["segments"] += len(segments)
    counts["hits"] += int(targets.hit.sum())
    return segments


def _calibration_rays(geometry, side, rng):
    """The rays of one pose's calibration view (``settings.CALIBRATION_VIEW_SHARE``): ``side``
    x ``side`` rays of an orbit camera from a random direction of ``rng``."""
    direction = rng.normal(size=3)
    return orbit_rays(geometry.vertices.min(0), geometry.vertices.max(0),
                      direction / np.linalg.norm(direction), side, side)


def reference_run(obj, capture, width, height, rest_pose=False, progress=None,
                  secondary=None):
    """Renders the true and embedded references of every pose in ``capture`` from an orbit
    camera each, and returns the embedding error and throughput as a JSON-ready dict; with
    ``secondary`` (``SecondarySettings``) the AO and shadow passes' too, each reference's
    from its own hits and the embedded one's from the true hits (suffix ``_true_hit``)."""
    check_image(width, height)
    mesh = capture.mesh
    heads = metric_heads(mesh)
    directions = orbit_viewpoints(len(capture.poses))
    truth, embedded, per_pose, secondaries = [], [], [], []
    clock = dict(prepare_s=0.0, evaluate_s=0.0, rays_s=0.0, walk_s=0.0, ground_truth_s=0.0,
                 embedded_reference_s=0.0, true_reference_s=0.0)
    segment_count = truncated = 0
    with PosedObject(obj, capture) as posed_object:
        host = posed_object.source.host
        start = time.perf_counter()
        rest_caster = posed_object.rest_caster
        clock["rest_surface_s"] = time.perf_counter() - start
        for index, pose in enumerate(capture.poses):
            geometry = (posed_object.rest_geometry() if rest_pose
                        else posed_object.geometry(pose))
            _pose_timings(clock, geometry)
            start = time.perf_counter()
            origins, rays = orbit_rays(geometry.vertices.min(0), geometry.vertices.max(0),
                                       directions[index], width, height)
            clock["rays_s"] += time.perf_counter() - start
            start = time.perf_counter()
            segments = traverse(geometry.cells, origins, rays)
            walked = time.perf_counter()
            truncated += segments.truncated                      # stopped by the walk's bounds
            targets = segment_targets(mesh, rest_caster, segments)
            grounded = time.perf_counter()
            embedded.append(embedded_reference(geometry.cells, segments, targets, len(rays)))
            clock["walk_s"] += walked - start
            clock["ground_truth_s"] += grounded - walked
            clock["embedded_reference_s"] += time.perf_counter() - grounded
            segment_count += len(segments)
            start = time.perf_counter()
            truth.append(true_reference(mesh, geometry.mesh_caster(mesh.triangles), origins,
                                        rays))
            clock["true_reference_s"] += time.perf_counter() - start
            per_pose.append(dict(compare(embedded[-1], truth[-1], mesh.size, heads,
                                         capture.grid.voxel_size),
                                 inverted_cells=geometry.inverted_cells()))
            if secondary is not None:
                start = time.perf_counter()
                secondaries.append(secondary_views(
                    {"true": truth[-1], "embedded": embedded[-1]}, origins, rays,
                    {"exact": exact_occluded(MeshCaster(geometry.vertices, mesh.triangles)),
                     "embedded": embedded_occluded(geometry.cells, mesh, rest_caster)},
                    mesh.size, secondary))
                per_pose[-1].update(_secondary_errors(secondaries[-1]))
                clock["secondary_s"] = clock.get("secondary_s", 0.0) + (time.perf_counter()
                                                                        - start)
            if progress is not None:
                progress(index + 1, len(capture.poses))
    rays_total = len(capture.poses) * width * height
    neural_path_s = clock["walk_s"] + clock["ground_truth_s"]
    embedding_error = compare(Passes.concatenate(embedded), Passes.concatenate(truth),
                              mesh.size, heads, capture.grid.voxel_size)
    if secondary is not None:
        embedding_error.update(_secondary_errors(
            {name: SecondaryPasses.concatenate([views[name] for views in secondaries])
             for name in secondaries[0]}))
    return {
        "object": mesh.name, "mode": capture.mode, "corners_follow": capture.corners_follow,
        "resolution": capture.grid.resolution,
        "poses": len(capture.poses), "rest_pose": rest_pose, "width": width, "height": height,
        "embedded_vs_true": embedding_error,
        **({} if secondary is None else {"secondary": secondary.describe()}),
        "per_pose": per_pose,
        "rays_per_s": rays_total / neural_path_s,
        "segments_per_s": segment_count / neural_path_s,
        "segments_per_ray": segment_count / rays_total, "truncated_rays": truncated,
        "timings": clock, "versions": _versions(host),
    }


def _secondary_errors(views):
    """The embedded reference's AO and shadow errors against the true one: from its own
    hits, and (suffix ``_true_hit``) from the true hits."""
    return {**compare_secondary(views["embedded"], views["true"]),
            **compare_secondary(views["embedded_true_hit"], views["true"], suffix="_true_hit")}


def _pose_timings(timings, geometry):
    """Adds a pose's preparation (deformed cells and entry BVH) and the rest of posing it
    (Blender's evaluation of the deformed mesh, on the thread that read it) to ``timings``."""
    timings["prepare_s"] += geometry.prepare_s
    timings["evaluate_s"] += geometry.evaluate_s


def _versions(host):
    """The versions that made a dataset or a reference run; ``host``: Blender's, as the
    pose source that evaluated the poses reports it."""
    from .. import __version__

    return {"vdnif": __version__, "blender": host,
            "numpy": np.__version__, "python": platform.python_version()}
