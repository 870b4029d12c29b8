"""Rest-space ground truth and the references on Warp BVHs against Blender's BVHTree and the
golden files of the pipeline before the kernels (``tests/golden/make_goldens.py``).

Tolerances (``assert_same_targets``). Both pipelines cast in float32; the kernel then refines
the distance to the hit triangle's plane in float64, where BVHTree's float32 distance is off
by a few float32 ulps of the coordinates divided by |cos theta| (theta between the segment
and the triangle's normal). Per segment, one of:
- same hit: distances within TOLERANCE (1e-6 object units), attributes (normal, albedo)
  within ATTRIBUTE_TOLERANCE (both are float32 records), same material;
- the same surface along a grazing segment: |d_new - d_old| |cos theta| <= TOLERANCE, and
  each side's attributes are those of its own hit point on that triangle (so they differ only
  because the float32 point moved along the surface);
- a surface at a segment end (within TOLERANCE of p0 or p1, where the margin clamps hits): a
  surface through a cell face along which the segment runs, which a float32 cast may or may
  not report (either of the two segments sharing the face may take it); what either side
  finds beyond it is not compared.
Anything else fails, and at most AMBIGUOUS_SHARE of the segments may take the last two.
Different triangles at the same distance must share a vertex (a hit on their common edge).
Targets read back from a dataset are stored in float16 (``training.packing``): each
tolerance then grows by STORED, one float16 ulp below 1 (of the segment's length for a
distance).
"""

import dataclasses
import json
import pathlib

import numpy as np
import pytest
from conftest import extension_oracle

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"
TOLERANCE = 1e-6             # object sizes, along the triangle normal
ATTRIBUTE_TOLERANCE = 1e-5   # unit normals and albedo
AMBIGUOUS_SHARE = 0.01       # rows that may differ within the rules above, at most
STORED = 2.0 ** -11          # a dataset's float16 targets (hit fraction, normal, albedo)


def face_normals(mesh):
    corners = mesh.vertices[mesh.triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return normal / np.linalg.norm(normal, axis=1, keepdims=True)


def attributes_at(mesh, p0, direction, distance, triangle):
    """(normal, albedo) of the points ``p0 + distance direction`` on ``triangle`` (numpy)."""
    point = p0 + distance[:, None] * direction
    oracle = extension_oracle("surface_casts")
    weights = oracle.barycentric(point, mesh.vertices[mesh.triangles[triangle]])
    normal = oracle.shading_normals(mesh.vertices, mesh.triangles, mesh.corner_normals,
                                    triangle, weights)
    return normal, oracle.surface_albedo(mesh, triangle, weights)[0]


def assert_same_targets(mesh, p0, p1, new, old, triangle, stored=0.0):
    """``new`` and ``old`` (SurfaceHits-like: hit, distance from p0, normal, albedo,
    material) of segments ``p0 -> p1`` (S, 3) agree by the module's rules; ``triangle`` (S,)
    is the triangle the new pipeline hit where it hit (-1 elsewhere); ``stored``: the
    rounding of targets read from a dataset (STORED), else 0. Returns the segments that
    differ beyond round-off."""
    length = np.linalg.norm(p1 - p0, axis=1)
    reach = TOLERANCE * mesh.size + stored * length
    attribute_tolerance = ATTRIBUTE_TOLERANCE + stored
    direction = (p1 - p0) / np.where(length > 0, length, 1.0)[:, None]
    both, neither = new.hit & old.hit, ~new.hit & ~old.hit
    offset = np.abs(new.distance - old.distance)
    differing = (new.hit != old.hit) | (both & (offset > reach))
    assert differing.mean() <= AMBIGUOUS_SHARE
    for name in ("normal", "albedo"):
        assert not getattr(new, name)[neither].any() and not getattr(old, name)[neither].any()
    same = both & ~differing
    for name in ("normal", "albedo"):
        np.testing.assert_allclose(getattr(new, name)[same], getattr(old, name)[same],
                                   atol=attribute_tolerance)
    np.testing.assert_array_equal(new.material[both], old.material[both])

    def at_end(side):
        return side.hit & (np.minimum(side.distance, length - side.distance) <= reach)

    end = differing & (at_end(new) | at_end(old))
    grazing = np.flatnonzero(differing & ~end)
    assert (both[grazing] & (triangle[grazing] >= 0)).all(), (
        "a hit only one side reports lies inside a segment")
    tri = triangle[grazing]
    cosine = np.abs(np.einsum("ij,ij->i", direction[grazing], face_normals(mesh)[tri]))
    assert (offset[grazing] * cosine <= reach[grazing]).all(), (
        "hit distances differ beyond float32")
    for side in (new, old):
        normal, albedo = attributes_at(mesh, p0[grazing], direction[grazing],
                                       side.distance[grazing], tri)
        np.testing.assert_allclose(side.normal[grazing], normal, atol=attribute_tolerance)
        np.testing.assert_allclose(side.albedo[grazing], albedo, atol=attribute_tolerance)
    return differing


def share_a_vertex(mesh, a, b):
    corners_a, corners_b = mesh.triangles[a], mesh.triangles[b]
    return (corners_a[:, :, None] == corners_b[:, None, :]).any(axis=(1, 2))


def walked_segments(core, obj, resolution, size):
    """A capture of ``obj`` and the segments of an orbit view of its first evaluation pose,
    walked as the references do."""
    poses = core("blender.poses")
    capture = core("blender.capture_scene").capture(
        obj, resolution, poses.evaluation_spec(poses.PoseSpec(count=1)), deform_corners=False)
    rays, traverse = core("tracing.rays"), core("tracing.traverse")
    with core("posed.geometry").PosedObject(obj, capture) as posed_object:
        geometry = posed_object.geometry(capture.poses[0])
        origins, directions = rays.orbit_rays(geometry.vertices.min(0),
                                              geometry.vertices.max(0),
                                              rays.orbit_viewpoints(1)[0], size, size)
        segments = traverse.traverse(geometry.cells, origins, directions)
        return capture, segments, posed_object.rest_caster


@pytest.mark.parametrize("scene", ["spot", "bunny"])
def test_segment_ground_truth_equals_blender_bvhtree(empty_scene, core, scene):
    obj = core("blender.scenes").demo_scene(scene)
    capture, segments, rest_caster = walked_segments(core, obj, 24, 96)
    mesh = capture.mesh
    found = core("tracing.groundtruth").segment_targets(mesh, rest_caster, segments)
    tree = core("blender.bvh").BVHCaster(mesh.vertices, mesh.triangles)
    expected = extension_oracle("surface_casts").segment_targets(mesh, tree, segments)
    assert expected.hit.sum() > 1000 and len(segments) > 10000
    assert_same_targets(mesh, segments.p0, segments.p1, found, expected, found.triangle)
    both = found.hit & expected.hit
    other = both & (found.triangle != expected.triangle)
    assert other.mean() < 0.001
    assert share_a_vertex(mesh, found.triangle[other], expected.triangle[other]).all()


def test_dataset_equals_the_golden_shard(empty_scene, core, tmp_path):
    """The arm's golden shard (R 12, 3 random poses of seed 0, 256 rays per pose, surface
    fraction 0.6, made before grazing rays existed) regenerated: the walk's arrays equal to
    float32 round-off, the ground truth within the module's rules."""
    obj = core("blender.scenes").demo_scene("arm")
    spec = core("blender.poses").PoseSpec(count=3, seed=0)
    capture = core("blender.capture_scene").capture(obj, 12, spec, deform_corners=False)
    header = core("posed.generate").generate_dataset(obj, capture, tmp_path, 256, 0.6, 0,
                                                       grazing_fraction=0.0)
    dataset = core("training.dataset")
    (_, [new]), (golden, [old]) = (dataset.read_dataset(tmp_path),
                                   dataset.read_dataset(GOLDEN / "arm-dataset"))
    golden_header = golden.header
    for key in ("object", "albedo_table", "poses", "inverted_cells"):
        assert getattr(header, key) == getattr(golden_header, key), key
    # The grid gained the rest mesh's fingerprint after the golden was made.
    assert dataclasses.replace(header.grid, mesh_fingerprint=None) == golden_header.grid
    assert len(header.grid.mesh_fingerprint) == 64
    # The heads gained the used-slot table after the golden was made: the arm uses slot 0.
    assert header.heads == dataclasses.replace(golden_header.heads, material_slots=(0,))
    assert header.counts.rays == golden_header.counts.rays
    # The calibration view (made after the golden) walks its 16x16 rays after each pose's
    # training rays, numbered after them; the training rays are drawn as before.
    assert header.view_rays == 256 and golden_header.view_rays == 0
    view = new["ray"] >= 256
    assert set(np.unique(new["ray"][view])) <= set(range(256, 512)) and view.any()
    new = {name: new[name][~view] for name in new.keys()}
    assert len(new["pose"]) == len(old["pose"])
    for name in ("pose", "ray"):
        np.testing.assert_array_equal(new[name], old[name])
    for name in ("p0", "p1", "seg_len", "rest_len", "t0"):
        np.testing.assert_allclose(new[name], old[name], rtol=1e-6, atol=1e-6)

    grid, mesh = capture.grid, capture.mesh
    p0, p1 = (old[name].astype(np.float64) * grid.extent + grid.origin for name in ("p0", "p1"))
    rest_len = old["rest_len"].astype(np.float64)

    class Records:
        def __init__(self, shard):
            self.hit = shard["hit"].astype(bool)
            self.distance = shard["hit_frac"] * rest_len
            self.normal, self.albedo = shard["normal"], shard["albedo"]
            self.material = shard["material"]

    # The new hits' triangles, for the angles: the kernel's on the records' segments, or
    # where float32 records moved a grazing segment off its surface, a float64 cast of them
    # grown by two margins at each end.
    groundtruth = core("tracing.groundtruth")
    triangle, *_ = groundtruth.rest_surface(mesh).cast_segments(
        p0, p1, np.zeros(len(p0), int), groundtruth.BOUNDARY_MARGIN * mesh.size)
    brute = extension_oracle("geometry").BruteForceCaster(mesh.vertices[mesh.triangles])
    length = np.linalg.norm(p1 - p0, axis=1)
    direction = (p1 - p0) / np.where(length > 0, length, 1.0)[:, None]
    grow = 2 * groundtruth.BOUNDARY_MARGIN * mesh.size
    triangle = np.where(triangle >= 0, triangle,
                        brute.cast(p0 - grow * direction, direction, length + 2 * grow)[0])
    new_records, old_records = Records(new), Records(old)
    assert old_records.hit.sum() > 1000
    assert_same_targets(mesh, p0, p1, new_records, old_records, triangle, STORED)


def test_references_equal_the_golden_metrics(empty_scene, core):
    """``references`` on the arm's 2 evaluation poses at 32x24 (R 12). Same rays, same hits
    (IoU and compared rays exact); the distance error may move by the old float32 distances'
    error, the normal error by their normals' float32 round-off."""
    obj = core("blender.scenes").demo_scene("arm")
    poses = core("blender.poses")
    # the poses tests/golden/make_goldens.py drew
    capture = core("blender.steps").evaluation_poses(obj, 12, poses.PoseSpec(count=2, seed=0),
                                                    pose_set=core("pose_sets").DEVELOPMENT_POSES)
    report = core("posed.generate").reference_run(obj, capture, 32, 24)
    golden = json.loads((GOLDEN / "arm-references.json").read_text())
    assert report["segments_per_ray"] == pytest.approx(golden["segments_per_ray"], abs=1e-12)
    for found, expected in zip([report["embedded_vs_true"], *report["per_pose"]],
                               [golden["embedded_vs_true"], *golden["per_pose"]]):
        assert found["hit_iou"] == expected["hit_iou"]
        assert found["compared_rays"] == expected["compared_rays"]
        assert found["distance_mae"] == pytest.approx(expected["distance_mae"],
                                                      abs=TOLERANCE)
        assert found["normal_error_deg"] == pytest.approx(expected["normal_error_deg"],
                                                          abs=1e-3)


def test_one_deformed_caster_per_posed_object_follows_the_pose_asked_for(empty_scene, core):
    """Built once, refit to whichever pose's ``mesh_caster`` is asked for, equal to a caster
    built on that pose alone; the rest pose uses the rest caster."""
    obj = core("blender.scenes").demo_scene("arm")
    capture = core("blender.capture_scene").capture(
        obj, 12, core("blender.poses").PoseSpec(count=2, seed=1), deform_corners=False)
    rays, references = core("tracing.rays"), core("tracing.references")
    surface = core("kernels.surface")
    with core("posed.geometry").PosedObject(obj, capture) as posed_object:
        first, second = (posed_object.geometry(pose) for pose in capture.poses)
        origins, directions = rays.orbit_rays(first.vertices.min(0), first.vertices.max(0),
                                              rays.orbit_viewpoints(1)[0], 32, 32)
        mesh = capture.mesh
        casters, passes = [], []
        for geometry in (first, second, first):
            casters.append(geometry.mesh_caster(mesh.triangles))
            passes.append(references.true_reference(mesh, casters[-1], origins, directions))
        alone = references.true_reference(
            mesh, surface.SurfaceCaster(second.vertices, mesh.triangles, second.normals),
            origins, directions)
        rest = posed_object.rest_geometry().mesh_caster(mesh.triangles)
        assert rest is posed_object.rest_caster
    assert casters[0] is casters[1] is casters[2]
    assert passes[0].hit.sum() > 100 and (passes[0].distance != passes[1].distance).any()
    for name in ("hit", "distance", "normal"):
        np.testing.assert_array_equal(getattr(passes[2], name), getattr(passes[0], name))
        np.testing.assert_array_equal(getattr(passes[1], name), getattr(alone, name))
