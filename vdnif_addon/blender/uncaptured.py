"""Deformations of a mesh that its rig does not capture, and those that nothing follows.

``check_captured`` tells whether copies of the armature and lattice modifiers capture every
deformation of the mesh (``blender.deform``): where they do not, the corners follow the
surface Blender evaluates instead (``posed.binding``). ``check_followable`` refuses by name
what even that cannot follow: a simulation (cloth, soft body, fluid, dynamic paint,
particles), whose shape in a pose depends on the frames simulated before it, not on the
pose. A topology that changes between poses is refused where the poses are evaluated
(``blender.deform``).

Copies of the armature and lattice modifiers move the corners as the rig moves the mesh; the
true mesh follows everything Blender evaluates. Any other modifier that moves vertices, and
any shape key whose weight changes from pose to pose, would move the true mesh away from
corners that follow the copies, so ``check_captured`` names them (and
``deform.check_deformers`` then has the corners follow the surface). What stays the same in
every pose is part of the rest mesh and is fine: a shape key that no curve or driver
animates (whatever its value), and modifiers that build the mesh from its own input alone
(subdivision, mirror, solidify...) placed before the rig. After the rig such a modifier
works on the posed mesh, which the corners do not follow (a subdivision after an armature
moves the surface by about 1 % of the object's size in a bent pose): there only modifiers
that keep every vertex where it is (triangulation, normals, UVs, weights) are fine. A
modifier before the rig that reads another object (an array's offset object, a mirror's or a
boolean's object) builds the rest mesh only while that object stays put: where it is
animated, driven, constrained or parented to something that moves (a bone of a posed
armature), the modifier is named.

It is judged from the object's data, not by evaluating poses: a deform modifier is named
even when it happens to be static (apply it to keep its shape), and an animation curve that
holds one value throughout does not count as animated.
"""

import re

from bpy_extras import anim_utils

from ..errors import VDNIFError
from .read_mesh import DEFORM_MODIFIER_TYPES

# Modifier types that leave every vertex where it is (topology by connectivity, normals,
# UVs, weights, physics bookkeeping): fine anywhere in the stack.
POSITION_KEEPING = frozenset({
    "COLLISION", "DATA_TRANSFER", "MASK", "NORMAL_EDIT", "PARTICLE_SYSTEM",
    "SURFACE", "TRIANGULATE", "UV_PROJECT", "UV_WARP", "VERTEX_WEIGHT_EDIT",
    "VERTEX_WEIGHT_MIX", "WEIGHTED_NORMAL",
})
# Modifier types that build new geometry from the mesh they receive alone (an edge split by
# angle splits other edges in another pose): the same in every pose before the rig, part of
# the rest mesh.
REST_BUILDING = frozenset({
    "ARRAY", "BEVEL", "BOOLEAN", "DECIMATE", "EDGE_SPLIT", "MIRROR", "MULTIRES", "REMESH",
    "SCREW", "SKIN", "SOLIDIFY", "SUBSURF", "WELD", "WIREFRAME",
})
# Geometry nodes that neither move points nor change the geometry (fields, inputs, shading
# flags, materials): a node tree of these alone, like Blender's "Smooth by Angle", keeps
# every vertex where it is.
STATIC_NODE_PREFIXES = ("FunctionNode", "ShaderNode", "GeometryNodeInput")
STATIC_NODES = frozenset({
    "NodeGroupInput", "NodeGroupOutput", "NodeReroute", "NodeFrame",
    "GeometryNodeSetShadeSmooth", "GeometryNodeSetMaterial", "GeometryNodeSetMaterialIndex",
})
_NAMED = r'\["((?:[^"\\]|\\.)*)"\]'
_KEY_BLOCK = re.compile(r"^key_blocks" + _NAMED)
_MODIFIER = re.compile(r"^modifiers" + _NAMED)


# Modifier types whose result depends on the simulation's history (frames before the pose),
# not on the pose: a random pose or a frame jumped to reads a stale or reset state.
SIMULATED = frozenset({
    "CLOTH", "SOFT_BODY", "FLUID", "DYNAMIC_PAINT", "EXPLODE", "PARTICLE_INSTANCE",
})


def check_followable(obj):
    """Raises a VDNIFError naming every enabled modifier of mesh object ``obj`` whose shape
    depends on a simulation rather than on the pose."""
    found = [f"modifier '{m.name}' ({m.type.lower().replace('_', ' ')})"
             for m in obj.modifiers if m.show_viewport and m.type in SIMULATED]
    if found:
        raise VDNIFError(f"'{obj.name}' is deformed by a simulation, which depends on the "
                         f"frames simulated before a pose, not on the pose: "
                         f"{', '.join(found)}; bake and apply it, or disable it")


def check_captured(obj):
    """Raises a VDNIFError naming every modifier and shape key of mesh object ``obj`` that
    deforms it in a way its armature and lattice modifiers do not capture."""
    animated = _animated_modifiers(obj)
    found, rig = [], None
    for modifier in obj.modifiers:
        kind = modifier.type.lower().replace("_", " ")
        if modifier.name in animated:
            found.append(f"modifier '{modifier.name}' ({kind}, {animated[modifier.name]} "
                         "settings)")
        elif not modifier.show_viewport or _keeps_positions(modifier):
            continue
        elif modifier.type in DEFORM_MODIFIER_TYPES:
            rig = rig or modifier
        elif modifier.type not in REST_BUILDING:
            found.append(f"modifier '{modifier.name}' ({kind})")
        elif rig is not None:
            found.append(f"modifier '{modifier.name}' ({kind} after the {rig.type.lower()} "
                         f"'{rig.name}')")
        else:
            found += [f"modifier '{modifier.name}' ({kind} before the rig, of object "
                      f"'{other.name}', which {why})"
                      for other, why in _moving_objects(modifier)]
    found += _moving_shape_keys(obj.data)
    if found:
        raise VDNIFError(f"'{obj.name}' is deformed by what only armature and lattice "
                         f"modifiers can follow here: {', '.join(found)}; apply, disable or "
                         "remove them (or move a modifier after the rig above it)")


def _animated_modifiers(obj):
    """{modifier name: "animated" or "driven"} of the modifiers whose settings change over
    time: the corners' copy of a modifier keeps the settings it had when it was made, and a
    static modifier with moving settings (a thickness, a level) is no longer static."""
    names = {}
    for path, how in _animated_paths(obj).items():
        match = _MODIFIER.match(path)
        if match:
            names.setdefault(_unescape(match.group(1)), how)
    return names


def _moving_objects(modifier):
    """[(object, why it moves)] of the objects a rest-building ``modifier`` reads that move
    from pose to pose (``_moves``)."""
    found = []
    for prop in modifier.bl_rna.properties:
        if prop.type != "POINTER" or getattr(prop.fixed_type, "identifier", "") != "Object":
            continue
        if modifier.type == "ARRAY" and prop.identifier == "offset_object" and not (
                modifier.use_object_offset):
            continue                    # set, but the array does not read it
        other = getattr(modifier, prop.identifier)
        why = None if other is None else _moves(other)
        if why is not None and all(other != seen for seen, _ in found):
            found.append((other, why))
    return found


def _moves(obj, seen=None):
    """Why object ``obj`` moves over time or with the pose (its transform animated or driven,
    an enabled constraint, a parent that is an armature or moves itself), else None."""
    seen = set() if seen is None else seen
    if obj.name in seen:
        return None
    seen.add(obj.name)
    for path, how in _animated_paths(obj).items():
        if path.startswith(("location", "rotation", "scale", "delta_", "matrix")):
            return f"is {how}"
    if any(constraint.enabled and not constraint.mute for constraint in obj.constraints):
        return "has constraints"
    parent = obj.parent
    if parent is not None:
        if parent.type == "ARMATURE":
            return f"follows the armature '{parent.name}'"
        if _moves(parent, seen) is not None:
            return f"has a parent '{parent.name}' that moves"
    return None


def _unescape(name):
    return name.replace('\\"', '"').replace("\\\\", "\\")


def _keeps_positions(modifier):
    if modifier.type == "NODES":
        return modifier.node_group is None or _static_tree(modifier.node_group)
    return modifier.type in POSITION_KEEPING


def _static_tree(tree, seen=None):
    seen = set() if seen is None else seen
    if tree in seen:
        return True
    seen.add(tree)
    for node in tree.nodes:
        if node.bl_idname == "GeometryNodeGroup":
            if node.node_tree is not None and not _static_tree(node.node_tree, seen):
                return False
        elif not (node.bl_idname in STATIC_NODES
                  or node.bl_idname.startswith(STATIC_NODE_PREFIXES)):
            return False
    return True


def _moving_shape_keys(mesh):
    """Descriptions of the shape keys of ``mesh`` that curves or drivers change, and of its
    animated vertex positions."""
    found = []
    key = mesh.shape_keys
    if key is not None:
        for path, how in _animated_paths(key).items():
            if path.startswith("eval_time") and not key.use_relative:
                found.append(f"shape key evaluation time ({how})")
            match = _KEY_BLOCK.match(path)
            block = key.key_blocks.get(_unescape(match.group(1))) if match else None
            if block is None or (key.use_relative and block == key.reference_key) or (
                    block.mute and not path.endswith(".mute")):
                continue
            text = f"shape key '{block.name}' ({how})"
            if text not in found:
                found.append(text)
    found += [f"mesh '{mesh.name}' vertex positions ({how})"
              for path, how in _animated_paths(mesh).items()
              if path.startswith(("vertices", "attributes"))][:1]
    return found


def _animated_paths(data_block):
    """{data path: "animated" or "driven"} of the properties of ``data_block`` that its
    active action, its NLA strips or its drivers change over time."""
    animation = data_block.animation_data
    if animation is None:
        return {}
    paths = {}
    sources = [(animation.action, animation.action_slot)] + [
        (strip.action, strip.action_slot) for track in animation.nla_tracks
        if not track.mute for strip in track.strips if not strip.mute]
    for action, slot in sources:
        for curve in _curves(action, slot):
            if not curve.mute and _varies(curve):
                paths.setdefault(curve.data_path, "animated")
    for driver in animation.drivers:
        if not driver.mute:
            paths[driver.data_path] = "driven"
    return paths


def _curves(action, slot):
    if action is None:
        return []
    if slot is None:
        return [c for layer in action.layers for strip in layer.strips
                for bag in strip.channelbags for c in bag.fcurves]
    bag = anim_utils.action_get_channelbag_for_slot(action, slot)
    return [] if bag is None else list(bag.fcurves)


def _varies(curve):
    """Whether an F-curve takes more than one value: keys or handles at different heights,
    or a modifier (noise, generator...) on it."""
    if len(curve.modifiers):
        return True
    heights = {round(y, 12) for point in curve.keyframe_points
               for y in (point.co[1], point.handle_left[1], point.handle_right[1])}
    return len(heights) > 1
