"""Small rigs as artists build them, each with its armature-only (or lattice-only) twin: a
two-bone box with a Subdivision after the armature, a corrective shape key driven by a bone,
a Corrective Smooth, a lattice with an animated shape key, a Mesh Deform cage moved by the
two bones, a Hook to an animated empty after the armature, a geometry-nodes Set Position
driven by the frame after the armature, and a topology-changing node tree after the
armature. The last three and their twins move over the frames (the bones are animated).
Shared by the surface-corner tests, ``tools/surface_corners_study.py`` and
``tools/artist_rigs_study.py`` (which put ``tests/support`` on their path)."""

import math

import bpy
import numpy as np
import scene_builders as sb
from mathutils import Matrix, Vector

RIGS = ("subdivision", "driven_key", "corrective_smooth", "lattice_key", "mesh_deform", "hook",
        "nodes_wobble")
FRAMES = (1, 40)
"""The timeline of the rigs that move over the frames: the first frame is their rest."""


def rigged_box(name="Box", counts=(8, 2, 2), spacing=0.25):
    box = sb.lattice_box(counts, spacing, name=name)
    sb.two_bone_rig(box)
    return box


def shape_key(obj, name, offset):
    """A shape key moving each vertex by ``offset(co)`` (V, 3) from the basis."""
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name=name)
    co = sb.mesh_vertices(obj)
    key.data.foreach_set("co", (co + offset(co)).astype(np.float32).ravel())
    return key


def joint_bulge(co):
    """Outward from the box's axis near its middle (the joint), up to 0.15."""
    centre = co.mean(0)
    radial = co - centre
    radial[:, 0] = 0
    length = np.linalg.norm(radial, axis=1, keepdims=True)
    near = np.exp(-((co[:, 0] - centre[0]) / 0.4) ** 2)[:, None]
    return 0.15 * near * radial / np.maximum(length, 1e-9)


def build(rig, full=True):
    """The rig ``rig`` (one of RIGS) in the empty scene: with ``full`` everything artists
    add, else its armature-only (lattice-only) twin. Returns (object, PoseSpec keywords)."""
    if rig == "lattice_key":
        box = sb.lattice_box((6, 3, 2), 0.25)
        lattice = sb.lattice_around(box, interpolation="KEY_LINEAR")
        lattice.data.points[0].co_deform = np.array(lattice.data.points[0].co) + 0.2
        lattice.data.points[26].co_deform = np.array(lattice.data.points[26].co) - 0.15
        if full:
            key = shape_key(box, "Swell", lambda co: 0.4 * (co - co.mean(0)) * (
                co[:, :1] > co[:, 0].mean()))
            key.value = 0.0
            key.keyframe_insert("value", frame=1)
            key.value = 1.0
            key.keyframe_insert("value", frame=20)
        bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, 20
        return box, dict(source="frames")
    if rig in ("mesh_deform", "hook", "nodes_wobble"):
        return _over_the_frames(rig, full), dict(source="frames")
    box = rigged_box()
    if full and rig == "subdivision":
        box.modifiers.new("Subdivision", "SUBSURF").levels = 2
    elif full and rig == "driven_key":
        key = shape_key(box, "Corrective", joint_bulge)
        driver = key.driver_add("value").driver
        variable = driver.variables.new()
        variable.type = "TRANSFORMS"
        target = variable.targets[0]
        target.id = bpy.data.objects["Rig"]
        target.bone_target = "Second"
        target.transform_type = "ROT_Z"
        target.transform_space = "LOCAL_SPACE"
        target.rotation_mode = "SWING_TWIST_Y"
        driver.expression = f"min(abs({variable.name}) / {math.radians(45)}, 1)"
    elif full and rig == "corrective_smooth":
        smooth = box.modifiers.new("Corrective Smooth", "CORRECTIVE_SMOOTH")
        smooth.iterations = 10
    return box, dict(max_angle_deg=50)


def _over_the_frames(rig, full):
    """The box bent by its two bones over ``FRAMES`` (straight at the first); with ``full``
    the Mesh Deform cage carries the bones instead of the box, or the Hook or the node tree
    is added after the armature."""
    if full and rig == "mesh_deform":
        box = sb.lattice_box((8, 2, 2), 0.25)
        # A closed cage a tenth of the box's size larger on every side, subdivided along the
        # bend so that it bends smoothly; the box is bound inside it at rest.
        cage = sb.lattice_box((8, 3, 3), 0.25, name="Cage")
        cage.data.transform(Matrix.Translation(Vector(
            sb.mesh_vertices(box).mean(0) - sb.mesh_vertices(cage).mean(0))))
        cage.hide_render = True
        cage.display_type = "WIRE"
        rig_object = sb.two_bone_rig(cage)
        deform = box.modifiers.new("Mesh Deform", "MESH_DEFORM")
        deform.object, deform.precision = cage, 4
        with bpy.context.temp_override(object=box, active_object=box):
            bpy.ops.object.meshdeform_bind(modifier=deform.name)
        bpy.context.evaluated_depsgraph_get()            # the evaluation that binds
        if not deform.is_bound:
            raise RuntimeError("the Mesh Deform modifier did not bind")
    else:
        box = rigged_box()
        rig_object = bpy.data.objects["Rig"]
    _animate_bend(rig_object)
    if full and rig == "hook":
        co = sb.mesh_vertices(box)
        handle = bpy.data.objects.new("Handle", None)
        bpy.context.scene.collection.objects.link(handle)
        handle.location = (co[:, 0].max(), co[:, 1].mean(), co[:, 2].max())
        bpy.context.view_layer.update()
        # Weights ramp from 0 to 1 over the box's last 0.6 along its length: the end follows
        # the handle, the middle does not, and no face is torn between them.
        group = box.vertex_groups.new(name="Handle")
        ramp = np.clip((co[:, 0] - co[:, 0].max() + 0.6) / 0.6, 0, 1)
        for index in np.flatnonzero(ramp):
            group.add([int(index)], float(ramp[index]), "REPLACE")
        hook = box.modifiers.new("Hook", "HOOK")
        hook.object, hook.vertex_group = handle, group.name
        hook.center = handle.location
        hook.matrix_inverse = handle.matrix_world.inverted()
        hook.falloff_type = "NONE"
        for frame, offset in ((FRAMES[0], (0, 0, 0)), (20, (0, 0.2, 0.15)),
                              (FRAMES[1], (0, -0.15, 0.25))):
            handle.location = tuple(np.add(tuple(hook.center), offset))
            handle.keyframe_insert("location", frame=frame)
    elif full and rig == "nodes_wobble":
        box.modifiers.new("Wobble", "NODES").node_group = _wobble_tree()
    bpy.context.scene.frame_set(FRAMES[0])
    return box


def _animate_bend(rig_object):
    """The second bone bends about Z over ``FRAMES``: straight, 50 degrees, -40 degrees."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    bone = rig_object.pose.bones["Second"]
    bone.rotation_mode = "XYZ"
    for frame, angle in ((FRAMES[0], 0), (20, 50), (FRAMES[1], -40)):
        bone.rotation_euler = (0, 0, math.radians(angle))
        bone.keyframe_insert("rotation_euler", frame=frame)


def _wobble_tree():
    """A node tree that lifts each point by (frame - first) * 0.004 * sin(4 x): nothing at
    the first frame, up to 0.156 at the last; the topology stays."""
    tree = bpy.data.node_groups.new("Wobble", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    source, sink = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    move = nodes.new("GeometryNodeSetPosition")
    position = nodes.new("GeometryNodeInputPosition")
    split = nodes.new("ShaderNodeSeparateXYZ")
    time = nodes.new("GeometryNodeInputSceneTime")

    def math_node(operation, a, b=None):
        node = nodes.new("ShaderNodeMath")
        node.operation = operation
        for socket, value in zip(node.inputs, (a, b)):
            if isinstance(value, (int, float)):
                socket.default_value = value
            elif value is not None:
                links.new(value, socket)
        return node.outputs[0]

    wave = math_node("SINE", math_node("MULTIPLY", split.outputs["X"], 4.0))
    amount = math_node("MULTIPLY", math_node("SUBTRACT", time.outputs["Frame"],
                                             float(FRAMES[0])), 0.004)
    lift = nodes.new("ShaderNodeCombineXYZ")
    links.new(math_node("MULTIPLY", wave, amount), lift.inputs["Z"])
    links.new(position.outputs["Position"], split.inputs[0])
    links.new(source.outputs[0], move.inputs["Geometry"])
    links.new(lift.outputs[0], move.inputs["Offset"])
    links.new(move.outputs["Geometry"], sink.inputs[0])
    return tree


def topology_changing():
    """A rigged box whose node tree after the armature deletes the faces above a height:
    the bent box loses faces that the straight one keeps."""
    box = rigged_box()
    tree = bpy.data.node_groups.new("Cut", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    source, sink = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    position = tree.nodes.new("GeometryNodeInputPosition")
    split = tree.nodes.new("ShaderNodeSeparateXYZ")
    above = tree.nodes.new("FunctionNodeCompare")
    above.operation = "GREATER_THAN"
    above.inputs["B"].default_value = 0.6
    delete = tree.nodes.new("GeometryNodeDeleteGeometry")
    tree.links.new(position.outputs["Position"], split.inputs[0])
    tree.links.new(split.outputs["Z"], above.inputs["A"])
    tree.links.new(source.outputs[0], delete.inputs["Geometry"])
    tree.links.new(above.outputs["Result"], delete.inputs["Selection"])
    tree.links.new(delete.outputs["Geometry"], sink.inputs[0])
    box.modifiers.new("Cut", "NODES").node_group = tree
    return box
