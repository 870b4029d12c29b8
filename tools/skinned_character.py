"""Writes a small rigged character as a skinned GLB or FBX file, the way such characters
arrive from other tools: one connected mesh (a skin-modifier humanoid, subdivided), an
armature of 13 bones with automatic weights, and two actions (a walk-like swing and a wave).

    python tools/skinned_character.py --out out/character.glb
    python tools/skinned_character.py --subdivide-after-rig 3 --out out/character.blend

Then ``batch.py -- train --mesh out/character.glb --pose-source frames`` poses it with its
own armature and actions. With ``--subdivide-after-rig N`` the body is the dense character
artists keep instead: a finer skin (each bone's edge in three) subdivided twice, about 5.9 k
triangles, skinned to the armature, with a Subdivision Surface modifier of N levels after
the armature (about 94 k, 375 k and 1.5 M evaluated triangles at N = 2, 3, 4); a .blend
file keeps the modifier (``train --blend FILE --object Character``).
"""

import argparse
import math
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import bpy  # isort: skip  (Blender's modules, addon_utils among them, come with it)
import addon_utils  # isort: skip

# name: (head, tail, parent, skin radius at the head)
BONES = {
    "Hips": ((0, 0, 0.95), (0, 0, 1.2), None, 0.17),
    "Chest": ((0, 0, 1.2), (0, 0, 1.45), "Hips", 0.19),
    "Head": ((0, 0, 1.45), (0, 0, 1.9), "Chest", 0.08),
    "UpperArm.L": ((0.2, 0, 1.45), (0.5, 0, 1.45), "Chest", 0.07),
    "LowerArm.L": ((0.5, 0, 1.45), (0.78, 0, 1.45), "UpperArm.L", 0.055),
    "UpperArm.R": ((-0.2, 0, 1.45), (-0.5, 0, 1.45), "Chest", 0.07),
    "LowerArm.R": ((-0.5, 0, 1.45), (-0.78, 0, 1.45), "UpperArm.R", 0.055),
    "Thigh.L": ((0.11, 0, 0.95), (0.12, 0, 0.52), "Hips", 0.1),
    "Shin.L": ((0.12, 0, 0.52), (0.12, 0, 0.08), "Thigh.L", 0.075),
    "Thigh.R": ((-0.11, 0, 0.95), (-0.12, 0, 0.52), "Hips", 0.1),
    "Shin.R": ((-0.12, 0, 0.52), (-0.12, 0, 0.08), "Thigh.R", 0.075),
}
TIP_RADIUS = {"Head": 0.13, "LowerArm.L": 0.045, "LowerArm.R": 0.045, "Shin.L": 0.06,
              "Shin.R": 0.06}
# Skin edges that join the limbs to the trunk (bones need not touch, the surface must).
JOINTS = (((0, 0, 1.45), (0.2, 0, 1.45)), ((0, 0, 1.45), (-0.2, 0, 1.45)),
          ((0, 0, 0.95), (0.11, 0, 0.95)), ((0, 0, 0.95), (-0.11, 0, 0.95)))
# action: frames and {bone: (axis, degrees at the middle frame, degrees at the last frame)}
ACTIONS = {
    "Walk": (1, 40, {"Thigh.L": (0, 35, -35), "Thigh.R": (0, -35, 35), "Shin.L": (0, -50, 0),
                     "Shin.R": (0, 0, -50), "UpperArm.L": (2, -30, 30),
                     "UpperArm.R": (2, -30, 30), "Chest": (1, 10, -10)}),
    "Wave": (1, 24, {"UpperArm.L": (1, 70, 40), "LowerArm.L": (2, 80, 20),
                     "Head": (2, 25, -25), "Chest": (0, 15, 5)}),
}


# The dense character's skin: each bone's and joint's edge cut in this many segments.
DENSE_SEGMENTS = 3


def build(subdivide_after_rig=None):
    """The character in an emptied file; with ``subdivide_after_rig`` levels the dense one
    (see the module)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    body = _skinned_body(1 if subdivide_after_rig is None else DENSE_SEGMENTS)
    rig = _armature()
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in (body, rig))
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    animation = rig.animation_data_create()
    for name, (first, last, channels) in ACTIONS.items():
        animation.action = None
        middle = (first + last) // 2
        for pose_bone in rig.pose.bones:
            pose_bone.rotation_mode = "XYZ"
            axis, mid, end = channels.get(pose_bone.name, (0, 0.0, 0.0))
            for frame, degrees in ((first, 0.0), (middle, mid), (last, end)):
                rotation = [0.0, 0.0, 0.0]
                rotation[axis] = math.radians(degrees)
                pose_bone.rotation_euler = rotation
                pose_bone.keyframe_insert("rotation_euler", frame=frame)
            pose_bone.rotation_euler = (0.0, 0.0, 0.0)
        animation.action.name = name
        animation.action.use_fake_user = True
        track = animation.nla_tracks.new()
        track.strips.new(name, first, animation.action)
        track.mute = True
    animation.action = None
    if subdivide_after_rig is not None:
        subdivision = body.modifiers.new("Subdivision", "SUBSURF")     # after the armature
        subdivision.levels = subdivision.render_levels = subdivide_after_rig
        # As an artist's file plays them: the actions one after the other on the timeline
        # (an exported file carries them as actions, which the importer lays out so).
        from vdnif_addon.blender.mesh_files import animation_on_timeline

        animation_on_timeline(rig, 1)
    return body


def _skinned_body(segments=1):
    """One connected surface around the bones: a Skin modifier over their edges, each edge
    cut in ``segments`` with radii between its ends'."""
    points, radii, edges = [], [], []
    index = {}
    for name, (head, tail, parent, radius) in BONES.items():
        for point, size in ((head, radius), (tail, TIP_RADIUS.get(name))):
            if point not in index:
                index[point] = len(points)
                points.append(point)
                radii.append(size if size is not None else radius)
        edges.append((index[head], index[tail]))
    edges += [(index[a], index[b]) for a, b in JOINTS]
    edges = _cut(edges, points, radii, segments)
    mesh = bpy.data.meshes.new("Character")
    mesh.from_pydata(points, edges, [])
    body = bpy.data.objects.new("Character", mesh)
    bpy.context.scene.collection.objects.link(body)
    body.modifiers.new("Skin", "SKIN")     # creates the skin radii layer
    for vertex, radius in zip(mesh.skin_vertices[0].data, radii):
        vertex.radius = (radius, radius)
    mesh.skin_vertices[0].data[0].use_root = True
    body.modifiers.new("Subdivision", "SUBSURF").levels = 2
    bpy.context.view_layer.objects.active = body
    for modifier in list(body.modifiers):
        bpy.ops.object.modifier_apply(modifier=modifier.name)
    body.data.shade_smooth()
    return body


def _cut(edges, points, radii, segments):
    """``edges`` each cut in ``segments``: the new points appended to ``points`` and
    ``radii`` (interpolated); the new edge list."""
    cut = []
    for a, b in edges:
        previous = a
        for step in range(1, segments):
            t = step / segments
            points.append(tuple((1 - t) * p + t * q for p, q in zip(points[a], points[b])))
            radii.append((1 - t) * radii[a] + t * radii[b])
            cut.append((previous, len(points) - 1))
            previous = len(points) - 1
        cut.append((previous, b))
    return cut


def _armature():
    data = bpy.data.armatures.new("Rig")
    rig = bpy.data.objects.new("Rig", data)
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    for name, (head, tail, parent, _) in BONES.items():
        bone = data.edit_bones.new(name)
        bone.head, bone.tail = head, tail
        if parent is not None:
            bone.parent = data.edit_bones[parent]
    bpy.ops.object.mode_set(mode="OBJECT")
    return rig


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, required=True,
                        help="the file to write: .glb, .gltf or .fbx (.blend with "
                             "--subdivide-after-rig)")
    parser.add_argument("--subdivide-after-rig", type=int, metavar="N",
                        help="the dense character: a Subdivision of N levels after the "
                             "armature")
    args = parser.parse_args(argv)
    if args.subdivide_after_rig is not None and args.subdivide_after_rig < 1:
        parser.error(f"--subdivide-after-rig {args.subdivide_after_rig}: the levels of a "
                     "subdivision are at least 1")
    if (args.subdivide_after_rig is None) == (args.out.suffix.lower() == ".blend"):
        parser.error("a .blend file is written with --subdivide-after-rig, and only then "
                     "(an exported file would apply the modifier)")
    build(args.subdivide_after_rig)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.out.suffix.lower() == ".blend":
        bpy.ops.wm.save_as_mainfile(filepath=str(args.out.resolve()), copy=True)
    elif args.out.suffix.lower() == ".fbx":
        addon_utils.enable("io_scene_fbx", default_set=False)
        bpy.ops.export_scene.fbx(filepath=str(args.out), add_leaf_bones=False,
                                 bake_anim_use_nla_strips=False)
    else:
        addon_utils.enable("io_scene_gltf2", default_set=False)
        bpy.ops.export_scene.gltf(filepath=str(args.out), export_format=(
            "GLB" if args.out.suffix.lower() == ".glb" else "GLTF_SEPARATE"))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
