"""Deformations that copies of the rig do not capture are named, and the corners then follow
the evaluated surface instead (tests/blender/test_surface_corners.py measures how well);
simulations stay refused. What stays the same in every pose (static shape keys, modifiers
that only build or shade the mesh) is captured by the copies, and the corners then follow
Blender's own evaluation exactly."""

import math
import types

import numpy as np
import pytest
import scene_builders as sb

TOLERANCE = 1e-5   # of the object size


def rigged_box(name="Box"):
    box = sb.lattice_box((8, 2, 2), 0.25, name=name)
    sb.two_bone_rig(box)
    return box


def refusal(core, obj):
    """The one line that says why copies of the rig do not capture ``obj``; its corners
    then follow the evaluated surface."""
    with pytest.raises(core("errors").VDNIFError) as caught:
        core("blender.uncaptured").check_captured(obj)
    message = str(caught.value)
    assert "\n" not in message and f"'{obj.name}'" in message
    assert core("blender.deform").check_deformers(obj) == "evaluated surface"
    return message


def capture_refusal(core, obj, spec=None):
    """The one-line message of the capture's refusal of ``obj``."""
    with pytest.raises(core("errors").VDNIFError) as caught:
        core("blender.capture_scene").capture(
            obj, 8, spec or core("blender.poses").PoseSpec(count=2))
    message = str(caught.value)
    assert "\n" not in message and f"'{obj.name}'" in message
    return message


def add_shape_key(obj, name="Bulge", value=0.0, lift=0.3):
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name=name)
    co = sb.mesh_vertices(obj)
    co[:, 2] += lift * (co[:, 0] > co[:, 0].mean())
    key.data.foreach_set("co", co.astype(np.float32).ravel())
    key.value = value
    return key


def push_nodes(name="Push"):
    """A geometry node tree that moves every point (Set Position with an offset)."""
    tree = _node_tree(name)
    move = tree.nodes.new("GeometryNodeSetPosition")
    move.inputs["Offset"].default_value = (0.0, 0.0, 0.1)
    _chain(tree, move)
    return tree


def smooth_by_angle_nodes(name="Smooth by Angle"):
    """A node tree like Blender's "Smooth by Angle": sets face smoothing from edge angles."""
    tree = _node_tree(name)
    angle = tree.nodes.new("GeometryNodeInputMeshEdgeAngle")
    below = tree.nodes.new("FunctionNodeCompare")
    below.inputs["B"].default_value = math.radians(30)
    smooth = tree.nodes.new("GeometryNodeSetShadeSmooth")
    smooth.domain = "EDGE"
    tree.links.new(angle.outputs["Unsigned Angle"], below.inputs["A"])
    tree.links.new(below.outputs["Result"], smooth.inputs["Shade Smooth"])
    _chain(tree, smooth)
    return tree


def _node_tree(name):
    import bpy

    tree = bpy.data.node_groups.new(name, "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    return tree


def _chain(tree, node):
    source = tree.nodes.new("NodeGroupInput")
    sink = tree.nodes.new("NodeGroupOutput")
    tree.links.new(source.outputs[0], node.inputs["Geometry"])
    tree.links.new(node.outputs["Geometry"], sink.inputs[0])


DEFORMING = ["CORRECTIVE_SMOOTH", "SMOOTH", "LAPLACIANSMOOTH", "MESH_DEFORM", "SURFACE_DEFORM",
             "DISPLACE", "WAVE", "HOOK", "CAST", "SIMPLE_DEFORM", "SHRINKWRAP", "WARP",
             "MESH_CACHE", "OCEAN", "NODES"]
SIMULATIONS = ["CLOTH", "SOFT_BODY"]


@pytest.mark.parametrize("kind", DEFORMING)
def test_a_deforming_modifier_is_named_and_followed_on_the_surface(empty_scene, core, kind):
    box = rigged_box()
    modifier = box.modifiers.new(f"My {kind.title()}", kind)
    if kind == "NODES":
        modifier.node_group = push_nodes()
    message = refusal(core, box)
    assert f"modifier 'My {kind.title()}' ({kind.lower().replace('_', ' ')})" in message


def test_a_model_on_the_copies_is_refused_once_its_rig_gains_what_they_miss(empty_scene,
                                                                           core):
    """A model records that its corners follow copies of the rig; captured again for it
    (evaluate, render, the panel) after the rig gained a modifier the copies miss, it is
    refused in one line that names the modifier and says to retrain, not rendered with
    corners that miss it. A model of the surface is still captured."""
    steps, deform = core("blender.steps"), core("blender.deform")
    box = rigged_box()
    spec = core("blender.poses").PoseSpec(count=2)

    def model(follow):
        return types.SimpleNamespace(corners_follow=follow, grid=types.SimpleNamespace(
            resolution=8), train_poses=[])

    on_copies = steps.model_capture(box, model(deform.ARMATURE_COPY), spec)
    assert on_copies.corners_follow == deform.ARMATURE_COPY
    box.modifiers.new("Relax", "CORRECTIVE_SMOOTH")
    with pytest.raises(core("errors").VDNIFError) as caught:
        steps.model_capture(box, model(deform.ARMATURE_COPY), spec)
    message = str(caught.value)
    assert "\n" not in message and "'Box'" in message
    assert "modifier 'Relax' (corrective smooth)" in message and "retrain" in message
    on_surface = steps.model_capture(box, model(deform.EVALUATED_SURFACE), spec)
    assert on_surface.corners_follow == deform.EVALUATED_SURFACE


@pytest.mark.parametrize("kind", SIMULATIONS)
def test_a_simulation_is_refused_by_name(empty_scene, core, kind):
    """A simulation's shape depends on the frames simulated before a pose: nothing that
    evaluates one pose follows it."""
    box = rigged_box()
    box.modifiers.new(f"My {kind.title()}", kind)
    message = capture_refusal(core, box)
    assert f"modifier 'My {kind.title()}' ({kind.lower().replace('_', ' ')})" in message
    assert "simulation" in message


def test_every_uncaptured_deformation_is_named_in_one_line(empty_scene, core):
    box = rigged_box()
    box.modifiers.new("Relax", "CORRECTIVE_SMOOTH")
    key = add_shape_key(box, "Smile")
    key.keyframe_insert("value", frame=1)
    key.value = 1.0
    key.keyframe_insert("value", frame=10)
    wave = box.modifiers.new("Ripple", "WAVE")
    wave.show_viewport = False              # a disabled modifier changes nothing
    message = refusal(core, box)
    assert "modifier 'Relax' (corrective smooth)" in message
    assert "shape key 'Smile' (animated)" in message
    assert "Ripple" not in message


def test_an_object_moved_only_by_time_is_captured_over_frames(empty_scene, core):
    """No rig, but a Wave moves the mesh at every frame: not static; random poses have
    nothing to pose (refused in one line), the frames follow it."""
    box = sb.lattice_box((4, 2, 2), 0.25)
    box.modifiers.new("Ripple", "WAVE")
    assert "modifier 'Ripple' (wave)" in refusal(core, box)
    assert "use the frames pose source" in capture_refusal(core, box)
    spec = core("blender.poses").PoseSpec(source="frames", count=3)
    capture = core("blender.capture_scene").capture(box, 8, spec)
    assert capture.mode == "animated" and capture.corners_follow == "evaluated surface"
    moved = np.abs(capture.corners - capture.grid.corner_positions()).max(axis=(1, 2))
    assert (moved > 1e-3).all(), "the wave should move the corners in every frame"


def test_animated_and_driven_shape_keys_are_named(empty_scene, core):
    box = rigged_box()
    smile = add_shape_key(box, "Smile")
    smile.keyframe_insert("value", frame=1)
    smile.value = 0.7
    smile.keyframe_insert("value", frame=20)
    frown = add_shape_key(box, "Frown \"deep\"", lift=-0.2)
    driver = frown.driver_add("value").driver
    driver.expression = "frame / 100"
    message = refusal(core, box)
    assert "shape key 'Smile' (animated)" in message
    assert "shape key 'Frown \"deep\"' (driven)" in message


def test_animated_modifier_settings_are_named(empty_scene, core):
    """A solidify whose thickness is keyframed moves vertices between frames, and the
    corners' copy of a modifier keeps the settings it was made with."""
    box = rigged_box()
    solidify = box.modifiers.new("Shell", "SOLIDIFY")
    solidify.keyframe_insert("thickness", frame=1)
    solidify.thickness = 0.2
    solidify.keyframe_insert("thickness", frame=10)
    assert "modifier 'Shell' (solidify, animated settings)" in refusal(core, box)


def corners_follow_blender(core, obj, spec):
    """Max distance over poses between the rest mesh's vertices deformed by the corners'
    deformer and Blender's evaluated mesh, in object sizes; and the capture."""
    capture = core("blender.capture_scene").capture(obj, resolution=8, spec=spec)
    rest = capture.mesh.vertices
    errors = []
    with core("blender.deform").CornerDeformer(obj, rest) as deformer:
        for pose in capture.poses:
            with core("blender.poses").posed(pose):
                followed = deformer.deformed()
                truth = core("blender.read_mesh").evaluated_surface(obj, capture.mesh)[0]
            errors.append(np.linalg.norm(followed - truth, axis=1).max())
    return max(errors) / capture.mesh.size, capture


@pytest.mark.parametrize("value", [0.0, 1.0])
def test_a_static_shape_key_is_part_of_the_rest_mesh(empty_scene, core, value):
    """An unanimated shape key (at 0 it changes nothing; at 1 it shapes the rest mesh) is
    accepted, and a keyframed one that holds one value is not animated."""
    box = rigged_box()
    basis = sb.mesh_vertices(box)
    key = add_shape_key(box, "Bulge", value=value)
    shaped = np.array([v.co for v in key.data])
    key.keyframe_insert("slider_max", frame=1)
    key.keyframe_insert("slider_max", frame=30)
    spec = core("blender.poses").PoseSpec(count=3, seed=2, max_angle_deg=50)
    error, capture = corners_follow_blender(core, box, spec)
    expected = shaped if value else basis
    assert np.abs(capture.mesh.vertices - expected).max() < 1e-6
    assert error < TOLERANCE


def test_position_keeping_modifiers_are_followed_after_the_armature(empty_scene, core):
    """Triangulation, weighted normals and a node tree that only sets smoothing keep every
    vertex where the armature put it: accepted after it, and the corners follow Blender."""
    box = rigged_box()
    box.modifiers.new("Triangulate", "TRIANGULATE")
    box.modifiers.new("Weighted Normal", "WEIGHTED_NORMAL")
    box.modifiers.new("Smooth by Angle", "NODES").node_group = smooth_by_angle_nodes()
    spec = core("blender.poses").PoseSpec(count=3, seed=4, max_angle_deg=50)
    error, capture = corners_follow_blender(core, box, spec)
    assert capture.mode == "armature" and error < TOLERANCE


@pytest.mark.parametrize("kind", ["SUBSURF", "MIRROR", "SOLIDIFY", "BEVEL", "EDGE_SPLIT"])
def test_geometry_building_modifiers_before_the_armature_are_followed(empty_scene, core, kind):
    """Modifiers that build geometry from the rest mesh (subdivision changes the vertex
    count) are part of the rest mesh before the armature: the corners take their weights
    from the built rest mesh and follow Blender's evaluation exactly."""
    box = rigged_box()
    box.modifiers.new("Built", kind)
    box.modifiers.move(1, 0)
    spec = core("blender.poses").PoseSpec(count=3, seed=6, max_angle_deg=50)
    error, capture = corners_follow_blender(core, box, spec)
    if kind == "SUBSURF":
        assert len(capture.mesh.vertices) > len(box.data.vertices)
    assert error < TOLERANCE


@pytest.mark.parametrize("kind", ["SUBSURF", "MIRROR", "SOLIDIFY", "BEVEL", "EDGE_SPLIT"])
def test_geometry_building_modifiers_after_the_armature_are_named(empty_scene, core, kind):
    """After the armature they work on the posed mesh, which copies of the armature do not
    follow: the corners follow the evaluated surface."""
    box = rigged_box()
    box.modifiers.new("Built", kind)
    message = refusal(core, box)
    assert f"modifier 'Built' ({kind.lower().replace('_', ' ')} after the armature " \
           "'Armature')" in message and "move a modifier after the rig above it" in message


def test_geometry_building_modifiers_after_the_armature_move_the_mesh(empty_scene, core,
                                                                     monkeypatch):
    """Why the copies do not follow them: with the check out of the way, the copies miss a
    subdivision after the armature by more than a thousandth of the object's size (before
    it, exactly 0 in the test above)."""
    box = rigged_box()
    box.modifiers.new("Built", "SUBSURF")
    spec = core("blender.poses").PoseSpec(count=3, seed=6, max_angle_deg=50)
    monkeypatch.setattr(core("blender.deform"), "check_captured", lambda obj: None)
    error, _ = corners_follow_blender(core, box, spec)
    print(f"subdivision after the armature: corners off by {error:.2e} of the size")
    assert error > 1e-3
