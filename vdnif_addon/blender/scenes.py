"""Scene sources: the embedded demo scenes, meshes from files (their own armature, else a
procedural rig), and objects from .blend files.

Every source returns the mesh object to capture. The procedural rigs are the same for the
demo scenes and for any mesh file without an armature of its own: an armature chain along
the longest axis with automatic weights, or a 3x3x3 lattice around the mesh, each animated
over frames 1..48.
"""

import math
import pathlib

import bpy
import numpy as np
from mathutils.kdtree import KDTree

from ..errors import VDNIFError
from ..mesh_input import check_input, check_mesh_file
from ..settings import DEMO_SCENES, RIGS
from .mesh_files import animation_on_timeline, first_line, import_mesh, own_armature
from .pieces import group_weights, normalized, riders
from .rig import bend_twist
from .trial_load import check_images, trial_load

FRAME_START, FRAME_END = 1, 48
LATTICE_MIN_SPAN = 0.6
"""The procedural lattice's thinnest axis, as a share of its longest: the coarsest
candidate grid (8 voxels) reaches up to 1.5 voxels, 0.19 of the longest side, past each
side of a flat mesh, so its corners need at least 0.38 plus the mesh's own thickness."""
MESHES = pathlib.Path(__file__).resolve().parents[2] / "assets" / "meshes"
WEIGHT_JUMP, JUMP_REACH = 0.5, 0.01
"""Automatic weights that differ by more than WEIGHT_JUMP (summed normalized bone weights: 0
alike, 2 on other bones) between two vertices closer than JUMP_REACH of the mesh's longest
side (a voxel at 96) fold the voxels between them in a bend: each voxel corner takes the
weights of its nearest surface point, so neighbouring corners turn apart and cells invert.
The procedural armature then weights by place along the chain instead. The bound lies
between the jumps whose voxels the development meshes show to follow and those they show
to fold (docs/results.md, "Development meshes")."""


def demo_scene(name, rig=None, meshes_dir=MESHES):
    """Builds the embedded demo scene ``name`` in the current (emptied) file."""
    if name not in DEMO_SCENES:
        raise VDNIFError(f"unknown scene '{name}': choose one of {', '.join(DEMO_SCENES)}")
    _reset_file()
    if name == "arm":
        obj = _segmented_cylinder("Arm")
        rig = rig or "armature"
    elif name == "lattice":
        obj = _subdivided_suzanne("Suzanne")
        rig = rig or "lattice"
    elif name == "spot":
        obj = import_mesh(meshes_dir / "spot.obj", name="Spot")
        _texture_material(obj, meshes_dir / "spot_texture.png")
        rig = rig or "armature"
    else:
        obj = import_mesh(meshes_dir / "stanford-bunny.obj", name="Bunny")
        _materials_split_in_slabs(obj)
        rig = rig or "lattice"
    return add_rig(obj, rig)


def mesh_scene(path, rig=None):
    """Imports a mesh file into an emptied file: a skinned mesh keeps the file's own
    armature and animation (frames over its actions), any other gets the procedural ``rig``
    (default armature)."""
    check_mesh_file(path)
    trial_load("mesh", path, "mesh file")
    _reset_file()
    obj = import_mesh(path)
    check_images("mesh file", path)
    armature = own_armature(obj)
    if armature is None:
        return add_rig(obj, rig or "armature")
    if rig is not None:
        raise VDNIFError(f"mesh file '{path}' has its own armature '{armature.name}': a "
                         "procedural rig is only for a mesh without one (leave out --rig)")
    animation_on_timeline(armature, FRAME_START)
    bpy.context.scene.frame_set(bpy.context.scene.frame_start)
    bpy.context.view_layer.objects.active = obj
    return obj


def blend_scene(path, object_name):
    """Opens a .blend file and returns the named object (checked later by capture)."""
    path = pathlib.Path(path)
    check_input(path, "blend file")
    trial_load("blend", path, "blend file")
    try:
        bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    except RuntimeError as exc:
        raise VDNIFError(f"cannot open blend file '{path}': {first_line(exc)}") from None
    check_images("blend file", path)
    return find_object(object_name)


def find_object(name=None):
    """The named object, or the active one when ``name`` is None."""
    if name is None:
        obj = bpy.context.view_layer.objects.active
        if obj is None:
            raise VDNIFError("no active object: select the mesh to capture or name it")
        return obj
    obj = bpy.data.objects.get(name)
    if obj is None:
        raise VDNIFError(f"no object named '{name}' in the scene")
    return obj


def find_camera(name=None):
    """The object named as camera (``neural.camera_rays`` checks that it is one), or the
    scene's active camera (None when it has none)."""
    if name is None:
        return bpy.context.scene.camera
    obj = bpy.data.objects.get(name)
    if obj is None:
        raise VDNIFError(f"no camera named '{name}' in the scene")
    return obj


def add_rig(obj, rig, riders_follow=True):
    """Adds the procedural armature or lattice rig with its animation to ``obj``;
    ``riders_follow`` False keeps bone heat's weights as they come wherever they weight every
    vertex: an armature's riding pieces (``pieces.riders``) weighted by themselves (what that
    costs: ``tools/separate_parts.py``), and no ``WEIGHT_JUMP`` check."""
    if rig not in RIGS:
        raise VDNIFError(f"unknown rig '{rig}': choose one of {', '.join(RIGS)}")
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAME_START, FRAME_END
    if rig == "armature":
        _armature_chain(obj, riders_follow=riders_follow)
    else:
        _bend_twist_lattice(obj)
    scene.frame_set(FRAME_START)
    bpy.context.view_layer.objects.active = obj
    return obj


def _reset_file():
    bpy.ops.wm.read_homefile(use_empty=True)


def _mesh_object(name, vertices, faces):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices.tolist(), [], faces)
    mesh.validate()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _segmented_cylinder(name, radius=0.25, length=3.0, rings=25, sides=16):
    """A capped cylinder along z with many rings, so it bends smoothly."""
    angles = np.linspace(0, 2 * math.pi, sides, endpoint=False)
    heights = np.linspace(-length / 2, length / 2, rings)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    vertices = np.concatenate([np.column_stack([ring, np.full(sides, z)]) for z in heights])
    faces = [(r * sides + s, r * sides + (s + 1) % sides,
              (r + 1) * sides + (s + 1) % sides, (r + 1) * sides + s)
             for r in range(rings - 1) for s in range(sides)]
    faces.append(tuple(reversed(range(sides))))
    faces.append(tuple((rings - 1) * sides + s for s in range(sides)))
    obj = _mesh_object(name, vertices, faces)
    for polygon in obj.data.polygons:
        polygon.use_smooth = len(polygon.vertices) == 4
    return obj


def _subdivided_suzanne(name):
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.active_object
    obj.name = name
    subdivision = obj.modifiers.new("Subdivision", "SUBSURF")
    subdivision.levels = 1
    bpy.ops.object.modifier_apply(modifier=subdivision.name)
    obj.data.shade_smooth()
    return obj


def _texture_material(obj, image_path):
    material = bpy.data.materials.new(f"{obj.name} texture")
    material.use_nodes = True
    nodes = material.node_tree.nodes
    principled = nodes["Principled BSDF"]
    texture = nodes.new("ShaderNodeTexImage")
    texture.image = bpy.data.images.load(str(image_path), check_existing=True)
    material.node_tree.links.new(texture.outputs["Color"], principled.inputs["Base Color"])
    obj.data.materials.clear()
    obj.data.materials.append(material)


def _constant_material(name, rgb):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*rgb, 1)
    return material


# The bunny's material slots: name and constant Base Color, one slab each along its longest
# axis (distinct hues, so a wrong material shows in the albedo pass too).
BUNNY_MATERIALS = (("Bunny clay", (0.8, 0.55, 0.35)), ("Bunny glaze", (0.2, 0.45, 0.85)),
                   ("Bunny moss", (0.3, 0.7, 0.25)))


def _materials_split_in_slabs(obj, materials=BUNNY_MATERIALS):
    """One constant material per slab of equal width across the longest axis (slot i for
    slab i), so material prediction has several boundaries to find."""
    mesh = obj.data
    mesh.materials.clear()
    for name, rgb in materials:
        mesh.materials.append(_constant_material(name, rgb))
    centres = np.empty(len(mesh.polygons) * 3)
    mesh.polygons.foreach_get("center", centres)
    centres = centres.reshape(-1, 3)
    axis = int(np.argmax(np.ptp(centres, axis=0)))
    low, high = centres[:, axis].min(), centres[:, axis].max()
    edges = low + (high - low) * np.arange(1, len(materials)) / len(materials)
    mesh.polygons.foreach_set("material_index",
                              np.searchsorted(edges, centres[:, axis]).astype(np.int32))


def _local_bounds(obj):
    """The bounds of the part of the mesh that frames it (``geometry.framing``: a far loose
    vertex does not stretch the rig)."""
    from ..geometry.framing import framing_bounds

    obj.data.calc_loop_triangles()
    triangles = np.empty(len(obj.data.loop_triangles) * 3, np.int64)
    obj.data.loop_triangles.foreach_get("vertices", triangles)
    return framing_bounds(_local_vertices(obj), triangles.reshape(-1, 3))


def _local_vertices(obj):
    """(V, 3) the mesh's vertex coordinates in its object's space."""
    co = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def _armature_chain(obj, bones=3, total_bend_degrees=120.0, riders_follow=True):
    """A chain of ``bones`` along the longest local axis, automatic weights (the riding
    pieces, ``pieces.riders``, weighted as the surface they ride on: ``follow_riders``), and
    an action that
    bends the chain by ``total_bend_degrees`` over the frame range."""
    lo, hi = _local_bounds(obj)
    axis = int(np.argmax(hi - lo))
    centre = 0.5 * (lo + hi)
    start, end = centre.copy(), centre.copy()
    start[axis], end[axis] = lo[axis], hi[axis]
    data = bpy.data.armatures.new(f"{obj.name} rig")
    armature = bpy.data.objects.new(f"{obj.name} rig", data)
    bpy.context.scene.collection.objects.link(armature)
    armature.matrix_world = obj.matrix_world.copy()
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    parent = None
    for index in range(bones):
        bone = data.edit_bones.new(f"Bone.{index}")
        bone.head = start + (end - start) * index / bones
        bone.tail = start + (end - start) * (index + 1) / bones
        bone.parent, bone.use_connect = parent, parent is not None
        parent = bone
    bpy.ops.object.mode_set(mode="OBJECT")
    for other in bpy.context.view_layer.objects:
        other.select_set(other in (obj, armature))
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    if not any(group.name.startswith("Bone.") for group in obj.vertex_groups):
        raise VDNIFError(f"automatic weights failed on '{obj.name}'")
    torn = (bone_weights(obj).sum(1) <= 0).any()
    if torn:
        _chain_weights(obj, bones, axis, lo[axis], hi[axis])
    if riders_follow:
        follow_riders(obj)
        if not torn and weight_jump(obj) > WEIGHT_JUMP:
            _chain_weights(obj, bones, axis, lo[axis], hi[axis])
            follow_riders(obj)
    bend = math.radians(total_bend_degrees / bones)
    for pose_bone in armature.pose.bones:
        pose_bone.rotation_mode = "XYZ"
        for frame, angle in ((FRAME_START, 0.0), (FRAME_END, bend)):
            pose_bone.rotation_euler = (angle, 0.0, 0.0)
            pose_bone.keyframe_insert("rotation_euler", frame=frame)
        pose_bone.rotation_euler = (0.0, 0.0, 0.0)
    return armature


def chain_bones(obj):
    """The names of ``obj``'s vertex groups of the procedural chain, ``Bone.i``, in the
    chain's order."""
    return sorted((g.name for g in obj.vertex_groups if g.name.startswith("Bone.")),
                  key=lambda name: int(name.split(".")[1]))


def bone_weights(obj):
    """(V, bones) the weights of every vertex of ``obj`` in the procedural chain's groups
    (``chain_bones``, in that order; 0 where a vertex is not in a group)."""
    return group_weights(obj, chain_bones(obj))


def weight_jump(obj):
    """The largest summed absolute difference of the normalized chain weights
    (``bone_weights``) between two vertices of ``obj`` closer than JUMP_REACH of its longest
    local side (0 for a mesh without them)."""
    weights = normalized(bone_weights(obj))
    vertices = _local_vertices(obj)
    if len(vertices) < 2:
        return 0.0
    reach = JUMP_REACH * float(np.ptp(vertices, axis=0).max())
    tree = KDTree(len(vertices))
    for index, co in enumerate(vertices):
        tree.insert(co, index)
    tree.balance()
    largest = 0.0
    for index, co in enumerate(vertices):
        near = [found for _, found, _ in tree.find_range(co, reach)]
        largest = max(largest, float(np.abs(weights[near] - weights[index]).sum(1).max()))
    return largest


def _chain_weights(obj, bones, axis, lo, hi):
    """Weights of the chain's bones by each vertex's place along ``axis`` (from ``lo`` to
    ``hi``, where the chain runs), replacing the automatic ones: full on a bone at its
    middle, blending linearly into the next bone's up to that one's middle.

    Blender's automatic weights (bone heat) leave a part of some meshes without any weight
    (thin plates with holes, letters, horns on a ball; docs/results.md, "Development
    meshes"); an armature leaves such vertices where they are while their neighbours turn,
    which tears the surface. These weights depend on the place along the chain alone, so
    both faces of a thin part move alike and nothing tears."""
    place = (_local_vertices(obj)[:, axis] - lo) / max(hi - lo, 1e-30) * bones - 0.5
    place = np.clip(place, 0.0, bones - 1.0)
    first = np.clip(np.floor(place).astype(int), 0, max(bones - 2, 0))
    share = place - first
    everyone = list(range(len(place)))
    for index in range(bones):
        name = f"Bone.{index}"
        group = obj.vertex_groups.get(name) or obj.vertex_groups.new(name=name)
        group.remove(everyone)
        weight = np.where(first == index, 1.0 - share, np.where(first + 1 == index, share, 0.0))
        for vertex in np.flatnonzero(weight > 0):
            group.add([int(vertex)], float(weight[vertex]), "REPLACE")


def follow_riders(obj):
    """Gives every riding vertex (``pieces.riders``) the chain weights of its nearest vertex
    of the largest piece.

    Blender's automatic weights weight each separate piece by itself, so an eye can follow
    the bones otherwise than the socket it sits in and slide in a bend, where one voxel
    gives both one motion (DESIGN section 4; docs/results.md, "The shaded image"). Weighted
    as the surface it rides on, it moves with it, as an artist parents eyes and buttons."""
    vertices, sources = riders(obj)
    if not len(vertices):
        return
    names = chain_bones(obj)
    weights = group_weights(obj, names, sources)       # before any group is changed
    for column, name in enumerate(names):
        group = obj.vertex_groups[name]
        group.remove(vertices.tolist())
        for row, vertex in enumerate(vertices):
            if weights[row, column] > 0:
                group.add([int(vertex)], float(weights[row, column]), "REPLACE")


def _bend_twist_lattice(obj, bend_degrees=60.0, twist_degrees=90.0):
    """A 3x3x3 lattice around ``obj`` with a shape key that bends and twists it along the
    longest axis, animated from 0 to 1 over the frame range."""
    lo, hi = _local_bounds(obj)
    axis = int(np.argmax(hi - lo))
    data = bpy.data.lattices.new(f"{obj.name} lattice")
    data.points_u = data.points_v = data.points_w = 3
    lattice = bpy.data.objects.new(f"{obj.name} lattice", data)
    bpy.context.scene.collection.objects.link(lattice)
    lattice.parent = obj
    rest = np.array([p.co for p in data.points])
    lattice.location = 0.5 * (lo + hi)
    # Blender holds a lattice's deformation constant outside its box, where the voxel
    # corners around a flat mesh lie: no axis thinner than LATTICE_MIN_SPAN of the longest
    # keeps every candidate resolution's corners inside.
    span = np.maximum(1.1 * (hi - lo), LATTICE_MIN_SPAN * 1.1 * (hi - lo).max())
    lattice.scale = span / np.ptp(rest, axis=0)
    modifier = obj.modifiers.new("Lattice", "LATTICE")
    modifier.object = lattice
    lattice.shape_key_add(name="Basis")
    key = lattice.shape_key_add(name="Bend and twist")
    unit = rest / np.ptp(rest, axis=0)
    bent = bend_twist(unit, axis, math.radians(bend_degrees), math.radians(twist_degrees))
    bent *= np.ptp(rest, axis=0)
    key.data.foreach_set("co", bent.astype(np.float32).ravel())
    for frame, value in ((FRAME_START, 0.0), (FRAME_END, 1.0)):
        key.value = value
        key.keyframe_insert("value", frame=frame)
    return lattice


