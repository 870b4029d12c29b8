"""Model metadata for tests, made as a model file's is read: plain data read back by
``ModelMetadata.from_dict``, so that every test's metadata passes the file's checks. It
imports no copy of the core: the caller's ``metadata`` module (``vdnif_addon.model.metadata``
or the extension's) gives the format version, so a test file keeps to one identity."""

GRID = {"origin": [-1.0, -2.0, 0.5], "voxel_size": 0.125, "dims": [8, 8, 4], "resolution": 8,
        "extent": 1.0, "occupied_voxels": 100, "mesh_fingerprint": "0" * 64}
TRAINING = {"status": "completed", "steps": 12, "seconds": 1.5, "samples_per_s": 1000.0,
            "validation": {"distance_mae": 0.01, "hits": 40.0},
            "log_variances": {"occlusion": 0.1},
            "val_poses": [1, 4], "world_size": 1, "config": {"steps": 12}}


def metadata_dict(metadata, network_config, **changes):
    """Plain metadata of a model built with ``network_config``, of ``metadata``'s format
    version: a made-up grid and one albedo row (and material slot) per material, unless
    ``changes`` say otherwise."""
    materials = network_config.heads.material_count
    data = {"version": metadata.FORMAT_VERSION, "object": "Arm", "object_size": 3.0,
            "variant": "proposed",
            "network_config": network_config.to_dict(), "grid": dict(GRID),
            "material_slots": list(range(materials)),
            "albedo_table": [[0.1 * (i + 1), 0.2, 0.3] for i in range(materials)],
            "thresholds": {"occlusion": 0.5, "candidate": 0.5}, "train_poses": [{"frame": 1.0}],
            "training": dict(TRAINING),
            "dataset": {"folder": "data", "shards": ["shard-000000-000003"], "poses": 3,
                        "segments": 4543},
            "vdnif_version": "0.1.0"}
    data.update(changes)
    return data


def capture_metadata(core, capture, **changes):
    """The ModelMetadata of a model trained on ``capture`` (``core``: the conftest fixture),
    its network config the default one with the capture's heads."""
    settings, mesh = core("settings"), capture.mesh
    config = settings.NetworkConfig(heads=settings.Heads(albedo=bool(mesh.albedo_varies),
                                                         material_count=mesh.material_count))
    data = metadata_dict(
        core("model.metadata"), config, object=mesh.name, object_size=mesh.size,
        grid=core("training.dataset").grid_header(capture.grid, mesh).to_dict(),
        material_slots=mesh.material_slots.tolist(), albedo_table=mesh.albedo_table().tolist(),
        train_poses=[])
    data.update(changes)
    return core("model.metadata").ModelMetadata.from_dict(data, "test.vdnif")
