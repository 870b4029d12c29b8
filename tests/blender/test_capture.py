"""Scene capture against Blender's own evaluation and exact cases."""

import math

import numpy as np
import pytest
import scene_builders as sb

TOLERANCE = 1e-5   # of the object size


def corner_index_of_vertices(grid, vertices):
    """Index into grid.corners of the corner at each vertex position (all must be corners)."""
    ijk = (vertices - grid.origin) / grid.voxel_size
    assert np.abs(ijk - np.round(ijk)).max() < 1e-6, "vertices are not on voxel corners"
    lookup = {tuple(c): i for i, c in enumerate(grid.corners.tolist())}
    return np.array([lookup[tuple(c)] for c in np.round(ijk).astype(int).tolist()])


def captured_vs_blender(core, obj, spec):
    """Max distance, per pose, between captured corners and Blender's evaluated vertices."""
    capture = core("blender.capture_scene").capture(obj, resolution=8, spec=spec)
    corner_of_vertex = corner_index_of_vertices(capture.grid, sb.mesh_vertices(obj))
    posed = core("blender.poses").posed
    errors = []
    for pose, corners in zip(capture.poses, capture.corners):
        with posed(pose):
            truth = sb.evaluated_vertices(obj)
        errors.append(np.linalg.norm(corners[corner_of_vertex] - truth, axis=1).max())
    return capture, np.array(errors)


def test_armature_corners_match_blender_where_they_coincide_with_vertices(empty_scene, core):
    box = sb.lattice_box((8, 2, 2), 0.25)
    sb.two_bone_rig(box)
    box.modifiers["Armature"].use_deform_preserve_volume = True
    spec = core("blender.poses").PoseSpec(count=4, seed=3, max_angle_deg=60)
    capture, errors = captured_vs_blender(core, box, spec)
    moved = np.abs(capture.corners - capture.grid.corner_positions()).max()
    assert capture.mode == "armature" and moved > 0.1, "poses did not deform the mesh"
    assert errors.max() < TOLERANCE * capture.mesh.size


def test_lattice_corners_match_blender_where_they_coincide_with_vertices(empty_scene, core):
    box = sb.lattice_box((4, 4, 2), 0.5)
    sb.lattice_around(box)
    spec = core("blender.poses").PoseSpec(count=4, seed=5, lattice_fraction=0.8)
    capture, errors = captured_vs_blender(core, box, spec)
    moved = np.abs(capture.corners - capture.grid.corner_positions()).max()
    assert capture.mode == "lattice" and moved > 0.05
    assert errors.max() < TOLERANCE * capture.mesh.size


def test_demo_animation_frames_match_blender(empty_scene, core):
    """Automatic weights and an action: timeline frames as the pose source."""
    scenes = core("blender.scenes")
    box = sb.lattice_box((8, 2, 2), 0.25)
    scenes.add_rig(box, "armature")
    spec = core("blender.poses").PoseSpec(source="frames", count=3)
    capture, errors = captured_vs_blender(core, box, spec)
    assert [p["frame"] for p in capture.poses] == pytest.approx([8.833, 24.5, 40.167], abs=1e-3)
    assert errors.max() < TOLERANCE * capture.mesh.size


@pytest.mark.parametrize("scene", ["arm", "lattice"])
def test_rest_pose_leaves_corners_unchanged(empty_scene, core, scene):
    obj = core("blender.scenes").demo_scene(scene)
    capture = core("blender.capture_scene").capture(obj, resolution=16, spec=core(
        "blender.poses").PoseSpec(source="frames", count=1))
    rest_pose = {"frame": 1.0}
    with core("blender.deform").CornerDeformer(obj, capture.grid.corner_positions()) as deformer:
        with core("blender.poses").posed(rest_pose):
            corners = deformer.deformed()
    error = np.abs(corners - capture.grid.corner_positions()).max()
    assert error < 1e-6 * capture.mesh.size


def test_affine_lattice_moves_corners_affinely(empty_scene, core):
    import bpy

    box = sb.lattice_box((4, 3, 2), 0.5)
    lattice = sb.lattice_around(box, margin=3.0, interpolation="KEY_LINEAR")
    linear = np.array([[1.2, 0.3, 0.0], [-0.1, 0.9, 0.2], [0.05, 0.0, 1.4]])
    shift = np.array([0.1, -0.2, 0.05])
    rest = np.array([p.co for p in lattice.data.points])
    for point, co in zip(lattice.data.points, rest @ linear.T + shift):
        point.co_deform = co
    bpy.context.view_layer.update()
    capture = core("blender.capture_scene").capture(box, resolution=8, spec=core(
        "blender.poses").PoseSpec(source="frames", count=1))
    to_lattice = np.array(lattice.matrix_world.inverted() @ box.matrix_world)
    from_lattice = np.linalg.inv(to_lattice)
    corners = capture.grid.corner_positions()
    in_lattice = corners @ to_lattice[:3, :3].T + to_lattice[:3, 3]
    moved = (in_lattice @ linear.T + shift) @ from_lattice[:3, :3].T + from_lattice[:3, 3]
    assert np.abs(capture.corners[0] - moved).max() < TOLERANCE * capture.mesh.size


def test_random_poses_touch_only_bones_that_move_the_mesh(empty_scene, core):
    import bpy

    box = sb.lattice_box((8, 2, 2), 0.25)
    rig = sb.two_bone_rig(box)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    spare = rig.data.edit_bones.new("Spare")
    spare.head, spare.tail = (0, 3, 0), (0, 4, 0)
    bpy.ops.object.mode_set(mode="OBJECT")
    rig.pose.bones["Second"].lock_rotation = (True, False, True)
    spec = core("blender.poses").PoseSpec(count=16, seed=1, max_angle_deg=30)
    capture = core("blender.capture_scene").capture(box, resolution=8, spec=spec)
    angles = np.array([[p["bones"][b] for b in ("First", "Second")] for p in capture.poses])
    assert all(set(p["bones"]) == {"First", "Second"} for p in capture.poses)
    assert np.abs(angles).max() <= math.radians(30) + 1e-9
    assert np.all(angles[:, 1, [0, 2]] == 0) and np.abs(angles[:, 1, 1]).max() > 0.1


def test_lattice_points_far_from_the_mesh_are_not_sampled(empty_scene, core):
    box = sb.lattice_box((2, 2, 2), 0.5)
    lattice = sb.lattice_around(box, margin=6.0, points=7, interpolation="KEY_LINEAR")
    moving = core("blender.rig").moving_lattice_points(box, box.modifiers["Lattice"])
    assert 0 < len(moving) < len(lattice.data.points)
    # The box spans a sixth of the cage, one cell of the 7x7x7 lattice, across its centre:
    # with linear interpolation exactly the 3x3x3 points around the centre reach it.
    assert len(moving) == 27
    assert set(moving) == {i for i, p in enumerate(lattice.data.points)
                           if np.abs(np.array(p.co)).max() <= 1 + 1e-6}


def test_inverted_cells_are_counted_per_pose(empty_scene, core):
    box = sb.lattice_box((4, 2, 2), 0.5)
    lattice = sb.lattice_around(box, interpolation="KEY_LINEAR")
    for point in lattice.data.points:   # mirror x: every cell turns inside out
        point.co_deform = (-point.co[0], point.co[1], point.co[2])
    capture = core("blender.capture_scene").capture(box, resolution=8, spec=core(
        "blender.poses").PoseSpec(source="frames", count=2))
    assert capture.inverted_cells.tolist() == [len(capture.grid.cells)] * 2
    assert capture.summary()["inverted_cells"] == [len(capture.grid.cells)] * 2


def test_static_mesh_is_one_rest_pose(empty_scene, core):
    box = sb.lattice_box((2, 2, 2), 0.5)
    capture = core("blender.capture_scene").capture(box, resolution=8)
    assert capture.mode == "static" and len(capture.poses) == 1
    np.testing.assert_array_equal(capture.corners[0], capture.grid.corner_positions())


def test_rest_mesh_attributes(empty_scene, core):
    """Flat faces keep their face normal at every corner; slots and UVs come through."""
    import bpy

    box = sb.lattice_box((2, 2, 2), 0.5)
    box.data.uv_layers.new(name="UV")
    for name, color in (("Red", (1, 0, 0, 1)), ("Blue", (0, 0, 1, 1))):
        material = bpy.data.materials.new(name)
        material.use_nodes = True
        material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = color
        box.data.materials.append(material)
    box.data.polygons[0].material_index = 1
    mesh = core("blender.read_mesh").read_rest_mesh(box)
    v = mesh.vertices[mesh.triangles]
    face_normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    face_normals /= np.linalg.norm(face_normals, axis=1, keepdims=True)
    np.testing.assert_allclose(mesh.corner_normals, face_normals[:, None].repeat(3, 1),
                               atol=1e-6)
    assert mesh.uvs.shape == (len(mesh.triangles), 3, 2)
    assert sorted(np.unique(mesh.material_index)) == [0, 1]
    assert mesh.heads() == {"occlusion": True, "distance": True, "normal": True,
                            "albedo": False, "material": True, "material_count": 2,
                            "material_slots": [0, 1]}
    np.testing.assert_allclose(mesh.albedo_table(), [[1, 0, 0], [0, 0, 1]])


@pytest.mark.parametrize("scene, expected", [
    ("spot", {"albedo": True, "material_count": 1}),
    ("bunny", {"albedo": False, "material": True, "material_count": 3}),
])
def test_demo_scene_heads(empty_scene, core, scene, expected):
    obj = core("blender.scenes").demo_scene(scene)
    mesh = core("blender.read_mesh").read_rest_mesh(obj)
    heads = mesh.heads()
    assert {k: heads[k] for k in expected} == expected
    if scene == "spot":
        texture = mesh.albedo[0].texture
        assert texture.shape == (1024, 1024, 3) and 0 <= texture.min() < texture.max() <= 1
        assert mesh.uvs is not None
    if scene == "bunny":        # three slots of distinct colours, each on a third of it
        table = mesh.albedo_table()
        assert len(np.unique(table.round(3), axis=0)) == 3
        shares = np.bincount(mesh.material_index, minlength=3) / len(mesh.material_index)
        assert shares.min() > 0.1


# --- bad input: an exception of the package's own type naming the object and the problem


def test_non_mesh_object_is_refused(empty_scene, core):
    import bpy

    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    with pytest.raises(core("errors").VDNIFError, match="'Cam' is a camera, not a mesh"):
        core("blender.capture_scene").capture(camera)


def test_empty_mesh_is_refused(empty_scene, core):
    import bpy

    obj = bpy.data.objects.new("Nothing", bpy.data.meshes.new("Nothing"))
    empty_scene.collection.objects.link(obj)
    with pytest.raises(core("errors").VDNIFError, match="'Nothing' is empty"):
        core("blender.capture_scene").capture(obj)


def test_armature_without_weights_is_refused(empty_scene, core):
    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    box.vertex_groups.clear()
    with pytest.raises(core("errors").VDNIFError,
                       match="armature 'Rig' has no bone weighting mesh 'Box'"):
        core("blender.capture_scene").capture(box)


def test_modifier_without_deformer_object_is_refused(empty_scene, core):
    box = sb.lattice_box((2, 2, 2), 0.5)
    box.modifiers.new("Lattice", "LATTICE")
    with pytest.raises(core("errors").VDNIFError,
                       match="lattice modifier 'Lattice' of 'Box' has no lattice object"):
        core("blender.capture_scene").capture(box)


@pytest.mark.parametrize("resolution", [3, 257])
def test_resolution_out_of_range_is_refused(empty_scene, core, resolution):
    box = sb.lattice_box((2, 2, 2), 0.5)
    with pytest.raises(core("errors").VDNIFError, match=f"'Box'.*{resolution}.*4..256"):
        core("blender.capture_scene").capture(box, resolution=resolution)


def test_missing_objects_and_files_are_refused(empty_scene, core, tmp_path):
    scenes, error = core("blender.scenes"), core("errors").VDNIFError
    with pytest.raises(error, match="no active object"):
        scenes.find_object()
    with pytest.raises(error, match="no object named 'Ghost'"):
        scenes.find_object("Ghost")
    garbage = tmp_path / "broken.obj"
    garbage.write_bytes(b"\x00\x01 not an obj")
    with pytest.raises(error, match="broken.obj"):
        scenes.import_mesh(garbage)
    with pytest.raises(error, match="does not exist"):
        scenes.import_mesh(tmp_path / "missing.ply")
    with pytest.raises(error, match="cannot read mesh file .*notes.txt"):
        scenes.import_mesh(tmp_path / "notes.txt")
