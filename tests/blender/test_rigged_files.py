"""Rigged files: a skinned mesh from a glTF, GLB or FBX file written by Blender's own
exporter (and a .blend) keeps the file's armature and its animation, and the corners follow
Blender's evaluation of that armature; only a mesh without an armature gets the procedural
rig. The reference is the authoring scene's own evaluation before export."""

import json
import math

import numpy as np
import pytest
import scene_builders as sb
from batch_runner import error_lines, run_batch

BONES = ("First", "Second")
# (name, bone, axis, degrees, last frame): two actions, each from rest at frame 1.
ACTIONS = (("Bend", "Second", 0, 60.0, 20), ("Twist", "First", 2, -40.0, 10))
# Frames of each action where the authoring scene is evaluated: integer frames, which the
# exporters sample exactly.
CHECKED_FRAMES = {"Bend": (7, 20), "Twist": (4,)}
EXACT = 1e-5   # of the object size (file formats store float32)


def author_character(tmp_path):
    """A skinned box with two bones and two actions, in an emptied file; returns the mesh,
    its rest vertices and its world-space vertices at CHECKED_FRAMES of each action."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    body = sb.lattice_box((8, 2, 2), 0.25, name="Body")
    rig = sb.two_bone_rig(body)
    body.parent = rig
    animation = rig.animation_data_create()
    for name, bone, axis, degrees, last in ACTIONS:
        animation.action = None
        # Every bone is keyed, as in a character's actions: a bone an action leaves out would
        # keep whatever pose the previous one left.
        for pose_bone in rig.pose.bones:
            pose_bone.rotation_mode = "XYZ"
            for frame, angle in ((1, 0.0), (last, math.radians(degrees))):
                rotation = [0.0, 0.0, 0.0]
                rotation[axis] = angle if pose_bone.name == bone else 0.0
                pose_bone.rotation_euler = rotation
                pose_bone.keyframe_insert("rotation_euler", frame=frame)
            pose_bone.rotation_euler = (0.0, 0.0, 0.0)
        animation.action.name = name
        animation.action.use_fake_user = True
    truth = {}
    for name, *_ in ACTIONS:
        animation.action = bpy.data.actions[name]
        for frame in CHECKED_FRAMES[name]:
            bpy.context.scene.frame_set(frame)
            truth[name, frame] = world(body, sb.evaluated_vertices(body))
    animation.action = bpy.data.actions[ACTIONS[0][0]]
    track = animation.nla_tracks.new()       # how exporters find the other actions
    track.strips.new(ACTIONS[1][0], 1, bpy.data.actions[ACTIONS[1][0]])
    track.mute = True
    bpy.context.scene.frame_set(1)
    return body, world(body, sb.mesh_vertices(body)), truth


def export(tmp_path, kind):
    import addon_utils
    import bpy

    path = tmp_path / f"character.{kind}"
    if kind == "fbx":
        addon_utils.enable("io_scene_fbx", default_set=False)
        bpy.ops.export_scene.fbx(filepath=str(path), add_leaf_bones=False, bake_anim=True,
                                 bake_anim_use_nla_strips=False, bake_anim_use_all_actions=True)
    elif kind == "blend":
        bpy.ops.wm.save_as_mainfile(filepath=str(path))
    else:
        addon_utils.enable("io_scene_gltf2", default_set=False)
        bpy.ops.export_scene.gltf(filepath=str(path), export_format=(
            "GLB" if kind == "glb" else "GLTF_SEPARATE"))
    return path


def world(obj, local):
    matrix = np.array(obj.matrix_world)
    return local @ matrix[:3, :3].T + matrix[:3, 3]


def action_offsets(armature):
    """{action name: frame of the scene where the action's frame 0 lies}."""
    data = armature.animation_data
    offsets = {}
    if data.action is not None:
        offsets[data.action.name] = 0.0
    for track in data.nla_tracks:
        for strip in track.strips if not track.mute else ():
            offsets[strip.action.name] = strip.frame_start - strip.action_frame_start
    # FBX names an action "<armature>|<action>".
    return {name.split("|")[-1]: offset for name, offset in offsets.items()}


@pytest.mark.parametrize("kind", ["glb", "gltf", "fbx", "blend"])
def test_a_skinned_file_keeps_its_own_armature_and_animation(empty_scene, core, tmp_path, kind):
    import bpy

    _, rest, truth = author_character(tmp_path)
    path = export(tmp_path, kind)
    scenes = core("blender.scenes")
    obj = (scenes.blend_scene(path, "Body") if kind == "blend" else scenes.mesh_scene(path))
    armature = core("blender.mesh_files").own_armature(obj)
    assert armature is not None
    assert sorted(b.name for b in armature.data.bones) == sorted(BONES)
    assert not any(o.name.endswith(" rig") for o in bpy.data.objects), "procedural rig added"
    # Each imported vertex is an authored one (files may split vertices along flat faces).
    imported_rest = world(obj, sb.mesh_vertices(obj))
    gap = np.linalg.norm(imported_rest[:, None] - rest[None], axis=2)
    authored = gap.argmin(axis=1)
    size = np.ptp(rest, axis=0).max()
    assert gap.min(axis=1).max() < EXACT * size
    offsets = action_offsets(armature)
    scene = bpy.context.scene
    capture = core("blender.capture_scene").capture(
        obj, 8, core("blender.poses").PoseSpec(source="frames", count=4))
    assert capture.mode == "armature"
    # A mesh file's actions all lie on the timeline; a .blend keeps its own timeline.
    assert set(offsets) == ({"Bend"} if kind == "blend" else {"Bend", "Twist"})
    with core("blender.deform").CornerDeformer(obj, capture.mesh.vertices) as deformer:
        for (name, frame), expected in truth.items():
            if name not in offsets:
                continue
            scene_frame = offsets[name] + frame
            assert scene.frame_start <= scene_frame <= scene.frame_end
            with core("blender.poses").posed({"frame": scene_frame}):
                evaluated = world(obj, sb.evaluated_vertices(obj))
                followed = world(obj, deformer.deformed())
            assert np.abs(expected - rest).max() > 0.05 * size, "the action moves nothing"
            assert np.linalg.norm(evaluated - expected[authored], axis=1).max() < EXACT * size
            assert np.linalg.norm(followed - evaluated, axis=1).max() < EXACT * size


def test_every_action_of_a_gltf_file_is_on_the_timeline(empty_scene, core, tmp_path):
    """Frames as poses cover both actions: they lie one after the other, each once."""
    author_character(tmp_path)
    obj = core("blender.scenes").mesh_scene(export(tmp_path, "glb"))
    armature = core("blender.mesh_files").own_armature(obj)
    strips = sorted((s.frame_start, s.frame_end, s.action.name)
                    for t in armature.animation_data.nla_tracks for s in t.strips)
    assert [name for *_, name in strips] != [] and {n for *_, n in strips} == {"Bend", "Twist"}
    assert armature.animation_data.action is None
    import bpy

    scene = bpy.context.scene
    assert scene.frame_start == strips[0][0] == 1
    assert strips[0][1] < strips[1][0] and scene.frame_end == strips[1][1]
    lengths = sorted(end - start for start, end, _ in strips)
    assert lengths == sorted(float(last - 1) for *_, last in ACTIONS)


def test_a_skinned_file_refuses_a_procedural_rig(empty_scene, core, tmp_path):
    author_character(tmp_path)
    path = export(tmp_path, "glb")
    with pytest.raises(core("errors").VDNIFError,
                       match="has its own armature 'Rig'.*leave out --rig"):
        core("blender.scenes").mesh_scene(path, "lattice")


def test_a_mesh_file_without_armature_gets_the_procedural_rig(empty_scene, core, tmp_path):
    """The same file without skin: the procedural armature chain, as before."""
    import addon_utils
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    sb.lattice_box((8, 2, 2), 0.25, name="Plain")
    addon_utils.enable("io_scene_gltf2", default_set=False)
    path = tmp_path / "plain.glb"
    bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB")
    obj = core("blender.scenes").mesh_scene(path)
    armature = core("blender.mesh_files").own_armature(obj)
    assert armature.name == "plain rig"
    assert [b.name for b in armature.data.bones] == ["Bone.0", "Bone.1", "Bone.2"]


@pytest.mark.slow
def test_the_batch_pipeline_trains_and_evaluates_a_skinned_glb(empty_scene, tmp_path):
    """capture, train and evaluate through the batch script on a skinned GLB, tiny size."""
    author_character(tmp_path)
    path = export(tmp_path, "glb")
    poses = ["--mesh", path, "--pose-source", "frames", "--resolution", "8"]
    code, out, err = run_batch("capture", *poses, "--poses", "3", "--json",
                               tmp_path / "capture.json")
    assert code == 0, err
    assert "captured 'character' (armature)" in out
    summary = json.loads((tmp_path / "capture.json").read_text())
    assert summary["poses"] == 3 and summary["pose_source"] == "frames"
    code, _, err = run_batch("train", *poses, "--poses", "3", "--rays-per-pose", "512",
                             "--steps", "20", "--batch", "1024", "--data", tmp_path / "data",
                             "--out", tmp_path / "model.vdnif", timeout=300)
    assert code == 0, err
    code, out, err = run_batch("evaluate", "--model", tmp_path / "model.vdnif", *poses,
                               "--poses", "2", "--width", "16", "--height", "16", "--json",
                               tmp_path / "eval.json", timeout=300)
    assert code == 0, err
    report = json.loads((tmp_path / "eval.json").read_text())
    assert report["object"] == "character"
    code, _, err = run_batch("capture", *poses, "--rig", "lattice")
    assert code == 1 and error_lines(err) == [
        f"vdnif: error: mesh file '{path}' has its own armature 'Rig': a procedural rig is "
        "only for a mesh without one (leave out --rig)"]


def test_a_rigged_blend_file_with_an_animated_shape_key_follows_its_surface(empty_scene, core,
                                                                            tmp_path):
    """The file's own armature poses the mesh, but a shape key its action animates would
    move the true mesh away from copies of the armature (named as the reason): the corners
    follow the evaluated surface. (The glTF importer leaves a morph target's animation in a
    muted NLA track, where it animates nothing.)"""
    body, *_ = author_character(tmp_path)
    body.shape_key_add(name="Basis")
    smile = body.shape_key_add(name="Smile")
    co = sb.mesh_vertices(body)
    co[:, 2] += 0.2 * (co[:, 0] > 1.0)
    smile.data.foreach_set("co", co.astype(np.float32).ravel())
    for frame, value in ((1, 0.0), (20, 1.0)):
        smile.value = value
        smile.keyframe_insert("value", frame=frame)
    obj = core("blender.scenes").blend_scene(export(tmp_path, "blend"), "Body")
    assert core("blender.mesh_files").own_armature(obj).name == "Rig"
    with pytest.raises(core("errors").VDNIFError,
                       match="'Body' .*: shape key 'Smile' \\(animated\\)"):
        core("blender.uncaptured").check_captured(obj)
    captured = core("blender.capture_scene").capture(
        obj, 8, core("blender.poses").PoseSpec(count=2))
    assert captured.corners_follow == "evaluated surface"


def test_an_unskinned_mesh_beside_a_skinned_one_joins_it(empty_scene, core, tmp_path):
    """Several meshes are joined into the skinned one, which keeps its Armature modifier
    whatever the importer's order; the extra mesh stays at rest (no weights)."""
    import bpy

    body, *_ = author_character(tmp_path)
    bpy.ops.mesh.primitive_cube_add(size=0.2, location=(1.0, 0.25, 1.0))
    bpy.context.active_object.name = "AHat"          # sorts before "Body"
    total = len(body.data.vertices) + 8
    obj = core("blender.scenes").mesh_scene(export(tmp_path, "glb"))
    assert [o.type for o in bpy.context.scene.objects if o is not obj] == ["ARMATURE"]
    assert core("blender.mesh_files").own_armature(obj).name == "Rig"
    assert len(obj.data.vertices) >= total


def test_meshes_skinned_to_two_armatures_are_refused(empty_scene, core, tmp_path):
    import bpy

    author_character(tmp_path)
    other = sb.lattice_box((4, 2, 2), 0.25, name="Other")
    other.location = (0.0, 2.0, 0.0)
    sb.two_bone_rig(other)
    bpy.context.view_layer.update()
    path = export(tmp_path, "glb")
    with pytest.raises(core("errors").VDNIFError, match="2 armatures .*only one armature"):
        core("blender.scenes").mesh_scene(path)
