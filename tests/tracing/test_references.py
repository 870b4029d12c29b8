"""Embedded vs true reference, and training datasets, on real scenes."""

import json
import pathlib

import numpy as np
import pytest
import scene_builders as sb


def references(core, obj, resolution, poses=1, rest_pose=False, size=48, spec=None):
    poses_module = core("blender.poses")
    spec = spec or poses_module.evaluation_spec(poses_module.PoseSpec(count=poses))
    capture = core("blender.capture_scene").capture(obj, resolution, spec, deform_corners=False)
    return core("posed.generate").reference_run(obj, capture, size, size, rest_pose=rest_pose)


@pytest.mark.parametrize("scene", ["spot", "bunny"])
def test_rest_pose_embedded_equals_a_direct_cast(empty_scene, core, scene):
    obj = core("blender.scenes").demo_scene(scene)
    report = references(core, obj, resolution=24, poses=2, rest_pose=True)
    error = report["embedded_vs_true"]
    assert error["hit_iou"] == 1.0 and error["compared_rays"] > 500
    assert error["distance_mae"] < 1e-5
    assert error["normal_error_deg"] < 0.01


def test_affine_lattice_embedded_equals_true(empty_scene, core):
    """A lattice that scales, shears and rotates its contents: trilinear cells are exact.
    The cage holds every voxel corner (outside a lattice Blender's map is not affine) and
    interpolates linearly (a 3-point B-spline lattice is only nearly affine: 0.04 degrees)."""
    import bpy
    from mathutils import Matrix

    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.active_object
    lattice = sb.lattice_around(obj, margin=3.0, interpolation="KEY_LINEAR")
    rotation = np.array(Matrix.Rotation(0.7, 3, (1, 2, 0.5)))
    linear = 1.3 * rotation @ np.array([[1, 0.4, 0], [0, 1, 0.2], [0, 0, 1]])
    for point in lattice.data.points:
        point.co_deform = linear @ np.array(point.co)
    bpy.context.view_layer.update()
    spec = core("blender.poses").PoseSpec(source="frames", count=1)
    report = references(core, obj, resolution=16, spec=spec, size=64)
    error = report["embedded_vs_true"]
    assert error["distance_mae"] < 1e-4 and error["hit_iou"] > 0.999
    assert error["normal_error_deg"] < 0.01


def test_embedding_error_falls_with_resolution_on_a_bent_arm(empty_scene, core):
    obj = core("blender.scenes").demo_scene("arm")
    poses = core("blender.poses")
    # two poses bent enough that the second-order error stands above the silhouettes' noise
    spec = poses.evaluation_spec(poses.PoseSpec(count=2),
                                 pose_set=core("pose_sets").DEVELOPMENT_POSES)
    errors = [references(core, obj, resolution, size=48, spec=spec)["embedded_vs_true"]
              for resolution in (16, 32, 64)]
    distance = [e["distance_mae"] for e in errors]
    assert distance[0] > distance[1] > distance[2] > 0


def test_inverted_cells_do_not_break_the_references(empty_scene, core):
    box = sb.lattice_box((4, 2, 2), 0.5)
    lattice = sb.lattice_around(box, interpolation="KEY_LINEAR")
    lattice.data.points[0].co_deform = (3.0, 3.0, 3.0)     # folds the cells at one corner
    spec = core("blender.poses").PoseSpec(source="frames", count=1)
    report = references(core, box, resolution=8, spec=spec, size=32)
    assert report["per_pose"][0]["inverted_cells"] > 0
    assert np.isfinite(report["embedded_vs_true"]["distance_mae"])


def test_dataset_shards_split_by_pose_range_equal_one_run(empty_scene, core, tmp_path):
    obj = core("blender.scenes").demo_scene("arm")
    spec = core("blender.poses").PoseSpec(count=4, seed=2)
    capture = core("blender.capture_scene").capture(obj, 16, spec, deform_corners=False)
    generate = core("posed.generate").generate_dataset
    generate(obj, capture, tmp_path / "whole", 256, seed=5)
    for pose_range in ((0, 1), (1, 4)):
        generate(obj, capture, tmp_path / "split", 256, seed=5, pose_range=pose_range)
    dataset = core("training.dataset")
    (whole_data, whole), (split_data, split) = (
        dataset.read_dataset(tmp_path / "whole"), dataset.read_dataset(tmp_path / "split"))
    assert len(split) == 2 and split_data.poses == whole_data.poses
    for name in dataset.ARRAYS:
        np.testing.assert_array_equal(np.concatenate([s[name] for s in split]), whole[0][name])
    shard = whole[0]
    hits = shard["hit"].astype(bool)
    assert 0.02 < hits.mean() < 0.5, "hits and misses should both be well represented"
    assert 0 <= shard["p0"].min() and shard["p1"].max() <= 1
    # unit normals, stored in float16 (training.packing): each component within 2^-12
    np.testing.assert_allclose(np.linalg.norm(shard["normal"][hits], axis=1), 1,
                               atol=3 ** 0.5 * 2.0 ** -12)
    assert set(np.unique(shard["pose"])) == {0, 1, 2, 3}
    whole_header = whole_data.header
    assert whole_header.heads.material is False and whole_header.counts.rays == 1024


def test_dataset_reader_refuses_bad_folders(empty_scene, core, tmp_path):
    dataset, error = core("training.dataset"), core("errors").VDNIFError
    with pytest.raises(error, match="does not exist"):
        dataset.read_dataset(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(error, match="holds no shards"):
        dataset.read_dataset(tmp_path / "empty")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "x.json").write_text(json.dumps({"hello": 1}))
    with pytest.raises(error, match="not a VDNIF dataset"):
        dataset.read_dataset(foreign)
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    golden = (pathlib.Path(__file__).resolve().parents[1] / "golden" / "arm-dataset"
              / "shard-000000-000003")
    (corrupt / "s.json").write_text(golden.with_suffix(".json").read_text())   # a good header
    (corrupt / "s.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(error, match="s.npz' cannot be read"):
        dataset.read_dataset(corrupt)
