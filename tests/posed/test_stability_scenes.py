"""Stability in Blender scenes: object scale and extreme poses (``--scale``, ``--deform``)
against an independent reference, and a mesh without area refused by name (the core's side
of the stability suite, without Blender, is ``test_stability.py``)."""

import argparse
import math

import numpy as np
import pytest

EXTREMES = ("bend:170", "twist:360", "stretch:4", "squash:0.1")


def stress_args(core, *argv):
    parser = argparse.ArgumentParser()
    core("cli.options").add_stress_options(parser)
    return parser.parse_args(list(argv))


def stressed_capture(core, scene, argv, spec, deform_corners=False):
    """A demo scene with the stress options ``argv`` applied, captured at R = 16."""
    obj = core("blender.scenes").demo_scene(scene)
    spec = core("blender.extremes").apply_stress(stress_args(core, *argv), obj, spec)
    return obj, core("blender.capture_scene").capture(obj, 16, spec, deform_corners=deform_corners)


def walk_pose(core, obj, capture, pose, size=32):
    """Walk, ground truth, both references and the inverted-cell count of one pose."""
    refs, rays = core("tracing.references"), core("tracing.rays")
    with core("posed.geometry").PosedObject(obj, capture) as posed_object:
        geometry = posed_object.geometry(pose)
        lo, hi = geometry.vertices.min(0), geometry.vertices.max(0)
        origins, directions = rays.orbit_rays(lo, hi, rays.orbit_viewpoints(1)[0], size, size)
        embedded, segments, targets = refs.embedded_passes(
            geometry.cells, capture.mesh, posed_object.rest_caster, origins, directions)
        truth = refs.true_reference(
            capture.mesh, geometry.mesh_caster(capture.mesh.triangles), origins, directions)
        cells = geometry.cells
        corners = cells.corners[cells.grid.cell_corners].reshape(-1, 3)
        inverted = core("geometry.voxels").inverted_cells(
            corners, np.arange(len(corners)).reshape(-1, 8))
    return dict(segments=segments, targets=targets, embedded=embedded, truth=truth,
                inverted=int(inverted.sum()), vertices=geometry.vertices,
                error=core("inference.metrics").compare(embedded, truth, capture.mesh.size))


@pytest.mark.parametrize("scene", ["arm", "lattice"])
def test_object_scale_leaves_errors_in_object_units_unchanged(empty_scene, core, scene):
    poses = core("blender.poses")
    spec = poses.evaluation_spec(poses.PoseSpec(count=2))
    runs = {}
    for scale in (1e-3, 1.0, 1e3):
        obj, capture = stressed_capture(core, scene, ["--scale", str(scale)], spec)
        with poses.posed(capture.poses[0]):
            vertices, _ = core("blender.read_mesh").evaluated_surface(obj, capture.mesh)
        report = core("posed.generate").reference_run(obj, capture, 48, 48)
        runs[scale] = capture, vertices, report["embedded_vs_true"]
    capture_1, vertices_1, error_1 = runs[1.0]
    assert error_1["distance_mae"] > 1e-5 and error_1["compared_rays"] > 300
    for scale in (1e-3, 1e3):
        capture, vertices, error = runs[scale]
        assert capture.poses == capture_1.poses
        # exactly S, up to Blender's float32 vertex storage
        assert capture.grid.voxel_size == pytest.approx(scale * capture_1.grid.voxel_size,
                                                        rel=1e-6)
        # the rig was scaled with the mesh: the posed mesh is the same shape S times larger
        np.testing.assert_allclose(vertices, scale * vertices_1,
                                   atol=1e-5 * scale * capture_1.mesh.size)
        for metric in ("distance_mae", "normal_error_deg", "hit_iou"):
            assert error[metric] == pytest.approx(error_1[metric], rel=0.05), metric


@pytest.mark.parametrize("deform", EXTREMES)
@pytest.mark.parametrize("scene", ["arm", "lattice"])
def test_extreme_poses_walk_finitely_and_report_inverted_cells(empty_scene, core, scene,
                                                               deform):
    spec = core("blender.poses").PoseSpec(count=1, seed=3)
    obj, capture = stressed_capture(core, scene, ["--deform", deform], spec,
                                    deform_corners=True)
    kind, amount = deform.split(":")
    assert capture.poses[0]["deform"] == {"object": obj.name, "kind": kind,
                                          "amount": float(amount)}
    result = walk_pose(core, obj, capture, capture.poses[0])
    segments, targets = result["segments"], result["targets"]
    for name in ("t0", "t1", "p0", "p1"):
        assert np.isfinite(getattr(segments, name)).all(), name
    for passes in (result["embedded"], result["truth"]):
        assert np.isfinite(passes.distance).all() and np.isfinite(passes.normal).all()
    assert np.isfinite(targets.distance).all() and np.isfinite(targets.normal).all()
    assert segments.truncated == 0 and len(segments) > 0 and result["embedded"].hit.any()
    # the walk's cells are the capture's: the reported count is the count of this pose
    assert result["inverted"] == capture.summary()["inverted_cells"][0] >= 0
    if (scene, kind) == ("lattice", "twist"):
        # the 3-point lattice turns its middle layer by 180 degrees: the cross-section
        # pinches to a point there and the cells through the pinch fold
        assert result["inverted"] > 0
    error = result["error"]       # the embedding stays usable even in these poses
    assert error["hit_iou"] > 0.75 and error["distance_mae"] < 0.01


def test_armature_extremes_follow_their_definition_on_the_rest_pose(empty_scene, core):
    """Frame 1 is the arm's rest pose: bend turns the chain's last bone by DEG, twist 360
    brings it back, and stretch/squash are affine (the whole arm scaled along its bone
    axis), which trilinear cells reproduce exactly with no inverted cell."""
    obj = core("blender.scenes").demo_scene("arm")
    extremes, posed = core("blender.extremes"), core("blender.poses").posed
    armature = obj.modifiers["Armature"].object
    first, last = armature.pose.bones[0], armature.pose.bones[-1]     # a chain of 3 bones
    rest_axis = np.array(last.bone.matrix_local)[:3, :3]
    spec = core("blender.poses").PoseSpec(count=1)
    capture = core("blender.capture_scene").capture(obj, 16, spec, deform_corners=False)
    channels = ("location", "rotation_euler", "rotation_quaternion", "scale")
    before = [[tuple(getattr(b, c)) for c in channels] for b in armature.pose.bones]
    for text in EXTREMES:
        deform = extremes.ExtremeDeform.parse(text)
        pose = {"frame": 1.0, "deform": deform.pose_key(obj)}
        with posed(pose):
            axes = np.array(last.matrix)[:3, :3]
            first_x = np.array(first.matrix)[:3, 0]
        if deform.kind == "bend":
            cosine = axes[:, 1] @ rest_axis[:, 1] / np.linalg.norm(axes[:, 1])
            assert math.degrees(math.acos(cosine)) == pytest.approx(170, abs=1e-3)
        elif deform.kind == "twist":        # 120 degrees per bone, 360 at the last one
            cosine = first_x @ np.array(first.bone.matrix_local)[:3, 0]
            assert math.degrees(math.acos(cosine)) == pytest.approx(120, abs=1e-3)
            np.testing.assert_allclose(axes, rest_axis, atol=1e-5)
        else:
            result = walk_pose(core, obj, capture, pose)
            length = np.ptp(result["vertices"][:, 2])
            assert length == pytest.approx(deform.amount * 3.0, rel=1e-5)
            assert result["inverted"] == 0
            assert result["error"]["distance_mae"] < 1e-5
            assert result["error"]["normal_error_deg"] < 0.01
    assert [[tuple(getattr(b, c)) for c in channels] for b in armature.pose.bones] == before


def test_lattice_extremes_move_the_points_as_defined(empty_scene, core):
    """On the rest pose: twist 360 keeps the end layers and turns the middle layer by 180
    degrees about the longest axis; stretch 4 scales the points along it about the centre.
    The shape keys are restored afterwards."""
    import bpy

    obj = core("blender.scenes").demo_scene("lattice")
    extremes, posed = core("blender.extremes"), core("blender.poses").posed
    lattice = obj.modifiers["Lattice"].object
    keys = lattice.data.shape_keys.key_blocks
    before = np.array([[p.co[:] for p in key.data] for key in keys])
    rest = before[0]
    axis = 0                       # Suzanne's longest side: the lattice's x
    along = rest[:, axis] - rest[:, axis].mean()
    middle = np.abs(along) < 1e-6
    across = [a for a in range(3) if a != axis]
    for text in ("twist:360", "stretch:4"):
        with posed({"frame": 1.0, "deform": extremes.ExtremeDeform.parse(text).pose_key(obj)}):
            depsgraph = bpy.context.evaluated_depsgraph_get()
            moved = np.array([p.co_deform[:]
                              for p in lattice.evaluated_get(depsgraph).data.points])
        expected = rest.copy()
        if text.startswith("twist"):
            expected[np.ix_(middle, across)] *= -1
        else:
            expected[:, axis] = rest[:, axis].mean() + 4 * along
        np.testing.assert_allclose(moved, expected, atol=1e-5)
        np.testing.assert_array_equal(
            np.array([[p.co[:] for p in key.data] for key in keys]), before)


def test_stress_options_parse_and_refuse_bad_values(empty_scene, core):
    import bpy

    extremes, error = core("blender.extremes"), core("errors").VDNIFError
    args = stress_args(core, "--scale", "1e-3", "--deform", "Bend:170")
    assert args.scale == 1e-3 and args.deform == extremes.ExtremeDeform("bend", 170.0)
    defaults = stress_args(core)
    assert defaults.scale == 1.0 and defaults.deform is None
    for option, value, message in (
            ("--deform", "bend:abc", "deform 'bend:abc' is not KIND:VALUE"),
            ("--deform", "bend", "deform 'bend' is not KIND:VALUE"),
            ("--deform", "wobble:3", "unknown deform kind 'wobble'"),
            ("--deform", "stretch:0", "stretch factor 0 must be at least 1"),
            ("--deform", "squash:2", "squash factor 2 must be in"),
            ("--deform", "twist:inf", "twist amount inf is not finite"),
            ("--scale", "0", "object scale 0 must be a finite number greater than 0"),
            ("--scale", "-2", "object scale -2 must be"),
            ("--scale", "nan", "object scale nan must be"),
            ("--scale", "big", "object scale 'big' is not a number")):
        with pytest.raises(error, match=message):
            stress_args(core, option, value)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    spec = core("blender.poses").PoseSpec()
    with pytest.raises(error, match="cannot twist 'Cube': it has no armature or lattice"):
        extremes.apply_stress(stress_args(core, "--deform", "twist:90"), cube, spec)
    assert extremes.apply_stress(stress_args(core, "--scale", "2"), cube, spec) is spec
    assert np.ptp(np.array([v.co[:] for v in cube.data.vertices]), axis=0) == \
        pytest.approx([4, 4, 4])


def test_a_scene_with_a_mesh_without_area_is_refused(empty_scene, core):
    """Only degenerate triangles (their walk finds nothing to hit: test_stability.py): the
    capture refuses the object by name."""
    import bpy

    line = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [0.5, 0.5, 0.5]])
    data = bpy.data.meshes.new("Needle")
    data.from_pydata(line.tolist(), [], [(0, 1, 2), (3, 1, 2)])
    needle = bpy.data.objects.new("Needle", data)
    bpy.context.scene.collection.objects.link(needle)
    with pytest.raises(core("errors").VDNIFError,
                       match="mesh object 'Needle' has no area: all its 2 triangles are "
                             "degenerate"):
        core("blender.capture_scene").capture(needle, 8)
