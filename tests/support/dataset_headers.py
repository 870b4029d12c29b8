"""A complete dataset header as plain JSON data (``training.header.DatasetHeader.from_dict``
reads it), for tests that write or train on hand-made shards."""


def header_dict(name="Ball", seed=0, pose_range=(0, 1), voxel_size=0.125, albedo=True,
                materials=1, segments=0):
    """The header of a shard of ``name``'s poses ``pose_range`` on an 8^3 grid of voxel size
    ``voxel_size`` at the origin, with ``segments`` rows."""
    start, stop = pose_range
    poses = stop - start
    return {
        "format": "vdnif-dataset", "version": 2, "object": name, "mode": "armature",
        "object_size": 1.0,
        "grid": {"origin": [0.0, 0.0, 0.0], "voxel_size": voxel_size, "dims": [8, 8, 8],
                 "resolution": 8, "extent": voxel_size * 8, "occupied_voxels": 100},
        "voxel_size": voxel_size,
        "heads": {"occlusion": True, "distance": True, "normal": True, "albedo": albedo,
                  "material": materials > 1, "material_count": materials},
        "albedo_table": [[0.5, 0.5, 0.5]] * materials,
        "poses": [{"frame": float(p)} for p in range(start, stop)],
        "pose_range": [start, stop], "seed": seed, "rays_per_pose": 16,
        "surface_fraction": 0.5, "grazing_fraction": 0.25, "inverted_cells": [0] * poses,
        "counts": {"rays": 16 * poses, "segments": segments, "hits": 0},
        "timings": {"total_s": 0.0}, "versions": {"vdnif": "test"}, "segments": segments,
    }
