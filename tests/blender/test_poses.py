"""Evaluation poses are disjoint from the training poses by construction (DESIGN section 4),
for timeline frames and random poses, against a training spec or a model's stored poses; a
request that cannot be disjoint is refused on one line naming the object."""

import itertools
import json

import numpy as np
import pytest
import scene_builders as sb


def frames_of(poses):
    return np.array([p["frame"] for p in poses])


def test_evaluation_frames_avoid_training_frames_whatever_the_counts(empty_scene, core):
    """Training, development and test frames: all apart, whatever the three counts (the
    evaluation sets need a finer step on this short range from about 47 frames on)."""
    poses = core("blender.poses")
    spacing = poses.MIN_FRAME_SPACING
    start, end = 1, 48
    for trained, evaluated in itertools.product(range(1, 25), repeat=2):
        training = frames_of(poses.frame_poses(start, end, trained))
        sets = [frames_of(poses.evaluation_frames(start, end, count, name, training))
                for count, name in ((evaluated, "development"), (2 * evaluated, "test"))]
        for count, frames in zip((evaluated, 2 * evaluated), sets):
            assert len(frames) == count
            assert np.all((frames >= start) & (frames <= end))
        # brute force: every pair of frames, training or evaluation, is apart
        everything = np.concatenate([training, *sets])
        gaps = np.abs(everything[:, None] - everything[None, :])[
            ~np.eye(len(everything), dtype=bool)]
        assert gaps.min() >= spacing, (trained, evaluated)
    # equal counts: a quarter frame after (development) and before (test) a whole frame
    training = frames_of(poses.frame_poses(1, 9, 4))
    assert training.tolist() == [2, 4, 6, 8]
    assert frames_of(poses.evaluation_frames(1, 9, 4, "development", training)).tolist() == [
        2.25, 4.25, 6.25, 8.25]
    assert frames_of(poses.evaluation_frames(1, 9, 4, "test", training)).tolist() == [
        2.75, 4.75, 6.75, 8.75]


def test_frames_that_cannot_be_apart_are_refused(empty_scene, core):
    poses, error = core("blender.poses"), core("errors").VDNIFError
    with pytest.raises(error, match=r"frame range 5..5 cannot hold 2 frames"):
        poses.frame_poses(5, 5, 2)
    with pytest.raises(error, match=r"cannot hold 1 test frames apart from the 1 "
                                    r"training frames"):
        poses.evaluation_frames(5, 5, 1, "test", [5.0])
    assert frames_of(poses.frame_poses(5, 5, 1)).tolist() == [5.0]   # one frame is fine
    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    scene = empty_scene
    scene.frame_start = scene.frame_end = 3
    spec = poses.PoseSpec(source="frames", count=1)
    with pytest.raises(error, match=r"^'Box': the frame range 3..3 cannot hold 1 test "
                                    r"frames apart from the 1 training frames"):
        core("blender.steps").evaluation_poses(box, 8, spec)


def test_evaluation_frames_avoid_the_frames_a_model_was_trained_on(empty_scene, core):
    """``evaluate`` knows the model's training frames, not their count: 3 trained frames,
    evaluated on 9 (9 frames spread over the range include all 3; the range holds only 6
    test frames at whole-frame steps, so they are at three quarters of half-frame steps)."""
    poses = core("blender.poses")
    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    empty_scene.frame_start, empty_scene.frame_end = 1, 7
    trained = poses.frame_poses(1, 7, 3)
    assert frames_of(trained).tolist() == [2, 4, 6]
    spread = frames_of(poses.frame_poses(1, 7, 9))
    assert np.isclose(spread[:, None], [2, 4, 6]).any(0).all()
    spec = poses.PoseSpec(source="frames", count=9)
    evaluated = core("blender.steps").evaluation_poses(box, 8, spec, trained=trained)
    frames = frames_of(evaluated.poses)
    assert len(frames) == 9 and np.abs(frames[:, None] - [2, 4, 6]).min() >= 0.125
    assert np.diff(np.sort(frames)).min() == 0.5 and np.all((frames % 0.5) == 0.375)


def test_random_evaluation_poses_are_drawn_again_where_they_repeat_training_poses(
        empty_scene, core):
    """A model trained on the stream that evaluation uses (training seed = evaluation seed):
    the evaluation poses skip the repeated ones and are still as many."""
    poses, capture = core("blender.poses"), core("blender.capture_scene").capture
    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    offset = poses.POSE_SETS[poses.TEST_POSES]       # evaluation's default set
    unlucky = poses.PoseSpec(count=3, seed=offset)
    trained = capture(box, 8, unlucky, deform_corners=False).poses
    evaluated = core("blender.steps").evaluation_poses(box, 8, poses.PoseSpec(count=5),
                                                      trained=trained)
    keys = {core("pose_sets").pose_key(p) for p in trained}
    assert len(evaluated.poses) == 5
    assert not keys & {core("pose_sets").pose_key(p) for p in evaluated.poses}
    # what an unchecked evaluation (the same seed) would have drawn: the training poses
    unchecked = capture(box, 8, poses.PoseSpec(count=5, seed=offset),
                        deform_corners=False).poses
    assert {core("pose_sets").pose_key(p) for p in unchecked[:3]} == keys
    assert evaluated.poses[:2] == unchecked[3:]


def test_random_poses_that_cannot_vary_are_refused(empty_scene, core):
    poses, error = core("blender.poses"), core("errors").VDNIFError
    box = sb.lattice_box((4, 2, 2), 0.5)
    rig = sb.two_bone_rig(box)
    for bone in rig.pose.bones:
        bone.lock_rotation = (True, True, True)
    with pytest.raises(error, match=r"^'Box': random poses keep repeating the 4 training "
                                    r"poses .* cannot be disjoint"):
        core("blender.steps").evaluation_poses(box, 8, poses.PoseSpec(count=4))


def test_pose_keys_survive_a_json_file(empty_scene, core):
    """A lattice pose's point indices come back from a file as strings, in text order."""
    import json

    pose_key = core("pose_sets").pose_key
    pose = {"frame": 1, "lattice": {"object": "Cage", "offsets": {2: [0.1, 0, 0],
                                                                  10: [0, 0.2, 0]}}}
    assert pose_key(json.loads(json.dumps(pose))) == pose_key(pose)
    assert pose_key(dict(pose, frame=2)) != pose_key(pose)


def test_evaluating_on_training_poses_is_refused(empty_scene, core):
    from model_metadata import capture_metadata
    from oracle_network import OracleNetwork

    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    capture = core("blender.capture_scene").capture(
        box, 8, core("blender.poses").PoseSpec(count=2), deform_corners=False)
    neural = core("posed.render")
    model = neural.SceneModel(
        network=OracleNetwork(capture.mesh, capture.grid),
        metadata=capture_metadata(core, capture, train_poses=capture.poses[1:]),
        grid=capture.grid, path="oracle.vdnif", device="cpu")
    with pytest.raises(core("errors").VDNIFError,
                       match=r"^'Box': the evaluation poses include poses that model "
                             r"'oracle.vdnif' was trained on"):
        neural.evaluate_model(box, capture, model, 8, 8)
    report, _ = neural.evaluate_model(box, capture, model, 8, 8, seen=True)
    assert report["unseen_poses"] is False


def test_development_and_test_poses_are_disjoint_and_each_study_uses_its_own(empty_scene, core):
    """Two named evaluation sets, each drawn by name: the bench's choices are made on the
    development poses, the reported tables (experiments) and ``evaluate`` use the test poses;
    the two and the training poses share no pose."""
    poses, capture = core("blender.poses"), core("blender.capture_scene").capture
    pose_sets = core("pose_sets")
    box = sb.lattice_box((4, 2, 2), 0.5)
    sb.two_bone_rig(box)
    spec = poses.PoseSpec(count=4)
    keys = {}
    drawn = {"training": spec, **{name: poses.evaluation_spec(spec, pose_set=name)
                                  for name in pose_sets.POSE_SETS}}
    for name, chosen in drawn.items():
        captured = capture(box, 8, chosen, deform_corners=False)
        keys[name] = {core("pose_sets").pose_key(p) for p in captured.poses}
        assert len(keys[name]) == 4
    assert set(keys) == {"training", pose_sets.DEVELOPMENT_POSES, pose_sets.TEST_POSES}
    for first, second in itertools.combinations(keys.values(), 2):
        assert not first & second
    with pytest.raises(core("errors").VDNIFError, match="unknown pose set 'other'"):
        poses.evaluation_spec(spec, pose_set="other")

    # evaluate (a model's capture, here of a model not yet trained on spec) draws test poses
    evaluated = core("blender.steps").model_capture(box, None, spec, evaluation=True,
                                                   resolution=8)
    assert {core("pose_sets").pose_key(p) for p in evaluated.poses} == keys[pose_sets.TEST_POSES]

    # the experiments evaluate on test poses of their own training spec
    runs = core("studies.experiment_runs")
    size = dict(runs.SIZES["quick"], poses=4, eval_poses=4, resolution=8)
    experiment = runs.Experiment(size, "unused", None, "cpu", None, ())
    drawn = {core("pose_sets").pose_key(p) for p in experiment.evaluation(box).poses}
    assert experiment.spec == spec and drawn == keys[pose_sets.TEST_POSES]


def test_references_measures_the_pose_set_it_is_asked_for(empty_scene, core, capsys, tmp_path):
    """``references --pose-set``: the embedding error on the development or the test poses
    (default: test), each what ``reference_run`` gives on a capture of that set's poses; the
    report says which set."""
    reports = {}
    for name in ("development", "test", None):
        out = tmp_path / f"{name}.json"
        chosen = [] if name is None else ["--pose-set", name]
        assert core("cli").main(["references", "--scene", "arm", "--resolution", "16",
                                 "--poses", "2", "--width", "16", "--height", "16", *chosen,
                                 "--json", str(out)]) == 0
        reports[name] = json.loads(out.read_text())
    assert reports[None]["pose_set"] == "test"
    assert reports[None]["per_pose"] == reports["test"]["per_pose"]
    arm = core("blender.scenes").find_object()          # the scene the commands loaded
    spec = core("pose_sets").PoseSpec(count=2)
    for name in ("development", "test"):
        captured = core("blender.steps").evaluation_poses(arm, 16, spec, pose_set=name)
        direct = core("posed.generate").reference_run(arm, captured, 16, 16)
        assert reports[name]["pose_set"] == name
        assert reports[name]["per_pose"] == direct["per_pose"]
    assert reports["development"]["per_pose"] != reports["test"]["per_pose"]
