"""The pose sets of both pose sources (DESIGN section 4): training, development and test
poses are disjoint, deterministic and, for frames, cover the range; every path that evaluates
takes its set (``evaluate``: test frames, the bench and the suggested resolution: development
frames); and the rest is the scene's first frame, whatever frame the scene shows."""

import itertools
import math

import numpy as np
import pytest
import scene_builders as sb

FINEST = 512
"""Quarter steps per frame at the finest step (1/128 frame): every evaluation frame is a whole
number of them after the range's first frame."""


def frames_of(poses):
    return np.array([p["frame"] for p in poses])


def set_of(frame, start):
    """'development' or 'test' by the documented rule, computed apart from the code: the
    distance from the first frame in finest quarter steps is a power of two times an odd
    number, 4k + 1 for a development frame and 4k + 3 for a test frame; else None."""
    units = (frame - start) * FINEST
    if units <= 0 or units != math.floor(units):
        return None
    units = int(units)
    while units % 2 == 0:
        units //= 2
    return "development" if units % 4 == 1 else "test"


def framed_box(empty_scene, start=1, end=30):
    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    empty_scene.frame_start, empty_scene.frame_end = start, end
    return box


@pytest.mark.parametrize("start, end", [(1, 2), (1, 3), (0, 9), (1, 48), (101, 350)])
def test_the_frame_sets_are_disjoint_deterministic_and_cover_the_range(empty_scene, core,
                                                                        start, end):
    """Short ranges too (1..2 holds one development frame at whole-frame steps, so larger
    counts take finer steps): every frame belongs to its set by the rule, none is within
    MIN_FRAME_SPACING of a frame of another set, a second call gives the same frames, and
    the frames reach from near the first frame to near the last without a gap much wider
    than an even spread's (at most a frame more than the range over the count, doubled
    where training frames are left out)."""
    poses = core("blender.poses")
    length = end - start
    for trained, count in itertools.product((1, 3, 8, 40), (1, 2, 5, 8, 33, 64)):
        training = frames_of(poses.frame_poses(start, end, trained))
        sets = {name: frames_of(poses.evaluation_frames(start, end, count, name, training))
                for name in ("development", "test")}
        for name, frames in sets.items():
            assert len(frames) == count and len(set(frames)) == count
            assert [set_of(f, start) for f in frames] == [name] * count, (trained, count)
            assert np.all((frames > start) & (frames <= end))
            again = frames_of(poses.evaluation_frames(start, end, count, name, training))
            assert again.tolist() == frames.tolist()
            alone = np.sort(frames_of(poses.evaluation_frames(start, end, count, name)))
            gaps = np.diff(np.concatenate([[start], alone, [end]]))
            assert gaps.max() <= length / count + 1 + 1e-9, (name, trained, count)
            gaps = np.diff(np.concatenate([[start], np.sort(frames), [end]]))
            assert gaps.max() <= 2 * (length / count + 1) + 1e-9, (name, trained, count)
        everything = np.concatenate([training, *sets.values()])
        apart = np.abs(everything[:, None] - everything[None])[
            ~np.eye(len(everything), dtype=bool)]
        assert apart.min() >= poses.MIN_FRAME_SPACING, (trained, count)


def test_whole_frame_steps_where_the_range_holds_them(empty_scene, core):
    """A quarter frame after a whole frame (development), a quarter before (test), on a range
    that holds them; on one that does not, the first step that does: halves on 1..5 for 8
    frames (4 whole steps), both sets."""
    poses = core("blender.poses")
    # 1.25 .. 249.25 are 249 development frames: the middle one of each of 8 equal runs
    assert frames_of(poses.evaluation_frames(1, 250, 8, "development")).tolist() == [
        1.25 + math.floor((i + 0.5) * 249 / 8) for i in range(8)]
    assert np.all(frames_of(poses.evaluation_frames(1, 250, 8, "test")) % 1 == 0.75)
    development = frames_of(poses.evaluation_frames(1, 5, 8, "development"))
    assert development.tolist() == [1.125, 1.625, 2.125, 2.625, 3.125, 3.625, 4.125, 4.625]
    assert np.all(frames_of(poses.evaluation_frames(1, 5, 8, "test")) % 0.5 == 0.375)


def test_a_range_too_short_is_refused_naming_the_object_and_the_range(empty_scene, core):
    """1..2 holds 128 frames of each set at 1/128-frame steps, not 129; one frame holds none."""
    poses, error = core("blender.poses"), core("errors").VDNIFError
    assert len(poses.evaluation_frames(1, 2, 128, "test")) == 128
    with pytest.raises(error, match=r"^the frame range 1..2 cannot hold 129 test frames "):
        poses.evaluation_frames(1, 2, 129, "test")
    box = framed_box(empty_scene, 4, 4)
    spec = poses.PoseSpec(source="frames", count=1)
    with pytest.raises(error, match=r"^'Box': the frame range 4..4 cannot hold 1 development "
                                    r"frames apart from the 1 training frames"):
        core("blender.steps").evaluation_poses(box, 8, spec, pose_set="development")
    with pytest.raises(error, match="name their pose set"):
        poses.PoseSpec(avoid=())
    with pytest.raises(error, match="unknown pose set 'held out'"):
        poses.PoseSpec(pose_set="held out")


def test_evaluation_takes_test_frames_and_choices_development_frames(empty_scene, core,
                                                                     monkeypatch):
    """``evaluate``'s capture (``model_capture``, against a model's stored training frames
    or a training spec) holds test frames; with the development set (the bench, ``evaluate
    --pose-set development``) development frames; the suggested resolution measures its
    candidates on development frames; none is a training frame."""
    poses, steps = core("blender.poses"), core("blender.steps")
    box = framed_box(empty_scene)
    spec = poses.PoseSpec(source="frames", count=6)
    training = core("blender.capture_scene").capture(box, 8, spec, deform_corners=False).poses
    trained = frames_of(training)
    assert trained.tolist() == frames_of(poses.frame_poses(1, 30, 6)).tolist()

    class Metadata:                     # what model_capture reads of a model file
        train_poses = training
        grid = type("Grid", (), {"resolution": 8})
        corners_follow = core("geometry.capture").ARMATURE_COPY

    for metadata in (Metadata, None):
        drawn = {}
        for name in ("development", "test"):
            captured = steps.model_capture(box, metadata, spec, evaluation=True, resolution=8,
                                           pose_set=name)
            drawn[name] = frames_of(captured.poses)
            assert [set_of(f, 1) for f in drawn[name]] == [name] * 6
            assert np.abs(drawn[name][:, None] - trained).min() >= poses.MIN_FRAME_SPACING
        default = steps.model_capture(box, metadata, spec, evaluation=True, resolution=8)
        assert frames_of(default.poses).tolist() == drawn["test"].tolist()

    resolution = core("blender.resolution")
    measured, capture = [], resolution.capture

    def recording(obj, size, chosen, **keywords):
        captured = capture(obj, size, chosen, **keywords)
        measured.append(frames_of(captured.poses))
        return captured

    monkeypatch.setattr(resolution, "capture", recording)
    resolution.suggest_resolution(box, spec, None, (8,), poses=2, size=16)
    assert len(measured) == 1 and [set_of(f, 1) for f in measured[0]] == ["development"] * 2


def test_random_development_and_test_poses_are_disjoint_and_deterministic(empty_scene, core):
    """Each set its own seed: 32 poses of each, one free axis per bone, share no pose with
    each other or the training poses, and are drawn again alike."""
    poses, capture = core("blender.poses"), core("blender.capture_scene").capture
    pose_key = core("pose_sets").pose_key
    box = sb.lattice_box((4, 2, 2), 0.5)
    rig = sb.two_bone_rig(box)
    for bone in rig.pose.bones:
        bone.lock_rotation = (True, False, True)
    spec = poses.PoseSpec(count=32)
    keys = {}
    for name in (None, "development", "test"):
        chosen = spec if name is None else poses.evaluation_spec(spec, pose_set=name)
        drawn = [capture(box, 8, chosen, deform_corners=False).poses for _ in range(2)]
        assert drawn[0] == drawn[1]
        keys[name] = {pose_key(p) for p in drawn[0]}
        assert len(keys[name]) == 32
    for first, second in itertools.combinations(keys.values(), 2):
        assert not first & second


def test_the_rest_is_the_first_frame_whatever_frame_the_scene_shows(empty_scene, core):
    """A lattice with an animated shape key (its mesh moves over the frames): captured while
    the scene shows frame 12, the rest mesh is Blender's mesh at frame 1 with the lattice
    off (read here directly), not at frame 12; the capture's corners and the model's mesh
    fingerprint are those of a capture made at frame 1; the scene is left at frame 12, and
    every frame change on the way is VDNIF's (``poses.posing``: the live preview ignores
    it), not the user's."""
    import artist_rigs
    import bpy

    box, keywords = artist_rigs.build("lattice_key")
    scene = bpy.context.scene
    lattice = box.modifiers[0]

    def unlatticed(frame):
        scene.frame_set(frame)
        lattice.show_viewport = False
        try:
            return sb.evaluated_vertices(box)
        finally:
            lattice.show_viewport = True
            bpy.context.view_layer.update()

    first, shown = unlatticed(1), unlatticed(12)
    assert np.abs(first - shown).max() > 0.05            # the key moves it between them
    capture, fingerprint = (core("blender.capture_scene").capture,
                            core("model.model_file").mesh_fingerprint)
    spec = core("blender.poses").PoseSpec(count=3, **keywords)
    posing, changes = core("blender.poses").posing, []

    def changed(scene, _depsgraph=None):
        changes.append((scene.frame_current, posing()))

    captured = {}
    for frame in (12, 1):
        scene.frame_set(frame)
        bpy.app.handlers.frame_change_post.append(changed)
        try:
            captured[frame] = capture(box, 8, spec)
        finally:
            bpy.app.handlers.frame_change_post.remove(changed)
        assert scene.frame_current == frame and scene.frame_subframe == 0
    assert (1, True) in changes and all(ours for _, ours in changes)
    np.testing.assert_allclose(captured[12].mesh.vertices, first, atol=1e-6)
    assert captured[12].corners_follow == "evaluated surface"
    assert fingerprint(captured[12].mesh) == fingerprint(captured[1].mesh)
    np.testing.assert_array_equal(captured[12].corners, captured[1].corners)
