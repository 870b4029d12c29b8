"""Small rigs as artists build them, each with its armature-only (or lattice-only) twin: a
two-bone box with a Subdivision after the armature, a corrective shape key driven by a bone,
a Corrective Smooth, a lattice with an animated shape key, and a topology-changing node tree
after the armature. Shared by the surface-corner tests and ``tools/surface_corners_study.py``
(which puts ``tests/support`` on its path)."""

import math

import bpy
import numpy as np
import scene_builders as sb

RIGS = ("subdivision", "driven_key", "corrective_smooth", "lattice_key")


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
