"""Mesh files (OBJ, PLY, glTF, FBX) imported as one mesh object, with the file's own armature
when its meshes are skinned, and that armature's animation laid out on the timeline.

A skinned file is rigged already: its armature, the Armature modifier that binds the mesh to
it and its actions are kept, so the file's own rig moves the mesh (``scenes.mesh_scene`` adds
the procedural rig only to a file without one). Importers also bring cameras, lights, empties
and helper meshes (bone shapes) that are no part of the object: they are removed, except the
objects the mesh and its armature hang from, whose transforms place them.
"""

import math
import pathlib

import bpy

from ..errors import VDNIFError
from ..mesh_input import check_mesh_file


def _import_gltf(path):
    _enable("io_scene_gltf2")
    # Bone shapes are display-only meshes outside the scene; skip creating them.
    bpy.ops.import_scene.gltf(filepath=path, disable_bone_shape=True)


def _import_fbx(path):
    _enable("io_scene_fbx")
    bpy.ops.import_scene.fbx(filepath=path)


MESH_IMPORTERS = {
    ".obj": lambda path: bpy.ops.wm.obj_import(filepath=path),
    ".ply": lambda path: bpy.ops.wm.ply_import(filepath=path),
    ".gltf": _import_gltf,
    ".glb": _import_gltf,
    ".fbx": _import_fbx,
}


def import_mesh(path, name=None):
    """Imports a mesh file and returns one mesh object (several are joined); a skinned
    mesh keeps its Armature modifier and armature object."""
    path = pathlib.Path(path)
    importer = MESH_IMPORTERS.get(path.suffix.lower())
    if importer is None:
        raise VDNIFError(f"cannot read mesh file '{path}': use one of "
                         f"{', '.join(sorted(MESH_IMPORTERS))}")
    check_mesh_file(path)     # it and the files it names, before the importer opens them
    before = set(bpy.data.objects)
    try:
        importer(str(path))
    except RuntimeError as exc:
        raise VDNIFError(f"cannot read mesh file '{path}': {first_line(exc)}") from None
    scene_objects = bpy.context.scene.objects
    new = [o for o in bpy.data.objects if o not in before and o.name in scene_objects]
    meshes = [o for o in new if o.type == "MESH" and len(o.data.polygons)]
    if not meshes:
        raise VDNIFError(f"mesh file '{path}' holds no faces")
    armatures = {m.object for o in meshes for m in _armature_modifiers(o)}
    if len(armatures) > 1:
        raise VDNIFError(f"mesh file '{path}' skins its meshes to {len(armatures)} armatures "
                         f"({', '.join(sorted(a.name for a in armatures))}): only one "
                         "armature per object is supported")
    # The joined object keeps the modifiers of the active one: a skinned mesh, if any.
    meshes.sort(key=lambda o: not _armature_modifiers(o))
    obj = _join(meshes)
    keep = {obj, *armatures}
    keep |= {parent for o in list(keep) for parent in _ancestors(o)}
    for other in [o for o in bpy.data.objects if o not in before and o not in keep]:
        bpy.data.objects.remove(other)
    obj.name = name or path.stem
    return obj


def own_armature(obj):
    """The armature object of ``obj``'s enabled Armature modifiers, or None."""
    armatures = {m.object for m in _armature_modifiers(obj)}
    return next(iter(armatures)) if armatures else None


def animation_on_timeline(armature, first_frame):
    """Lays the armature's actions one after another on the timeline from ``first_frame``
    and sets the scene's frame range over them, so frames as poses cover every action.
    The actions are the active one, those held in NLA tracks (as the glTF importer leaves
    them) and any other action of the file that moves the armature's bones (as the FBX
    importer leaves them); call it on a file holding only the imported one. Returns the
    number of actions (0: the armature is not animated)."""
    data = armature.animation_data_create()
    bones = tuple(f'pose.bones["{bone.name}"]' for bone in armature.pose.bones)
    actions = []
    for action in [data.action, *(s.action for t in data.nla_tracks for s in t.strips),
                   *sorted((a for a in bpy.data.actions if _moves(a, bones)),
                           key=lambda a: a.name)]:
        if action is not None and action not in actions:
            actions.append(action)
    if not actions:
        return 0
    scene = bpy.context.scene
    if len(actions) == 1 and not data.nla_tracks:
        start, end = actions[0].frame_range
        scene.frame_start, scene.frame_end = math.floor(start), math.ceil(end)
        return 1
    while data.nla_tracks:
        data.nla_tracks.remove(data.nla_tracks[0])
    data.action = None
    track = data.nla_tracks.new()
    start = first_frame
    for action in actions:
        strip = track.strips.new(action.name, start, action)
        start = math.ceil(strip.frame_end) + 1
    scene.frame_start, scene.frame_end = first_frame, start - 1
    return len(actions)


def first_line(exc):
    return str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__


def _enable(module):
    import addon_utils

    addon_utils.enable(module, default_set=False)


def _armature_modifiers(obj):
    return [m for m in obj.modifiers
            if m.type == "ARMATURE" and m.show_viewport and m.object is not None]


def _moves(action, bones):
    """Whether ``action`` has a curve on one of ``bones`` (a tuple of data path prefixes)."""
    return any(curve.data_path.startswith(bones) for layer in action.layers
               for strip in layer.strips for bag in strip.channelbags for curve in bag.fcurves)


def _ancestors(obj):
    while obj.parent is not None:
        obj = obj.parent
        yield obj


def _join(meshes):
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in meshes)
    bpy.context.view_layer.objects.active = meshes[0]
    if len(meshes) > 1:
        bpy.ops.object.join()
    return bpy.context.view_layer.objects.active
