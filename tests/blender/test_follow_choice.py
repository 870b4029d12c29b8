"""How the corners of an armature or lattice rig follow it in training: the copied modifiers
unless the surface binding's embedding error on development poses is better by a margin (a
lattice as thin as its mesh holds the corners outside it still); the choice goes into the
dataset and the model file, and evaluation and rendering of the model follow as it says
(a file written before the record reads as the copies)."""

import dataclasses
import pathlib

from thin_lattice import thin_lattice_slab

RESOLUTION, POSES, SIZE = 16, 2, 48
GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"
TINY = dict(steps=3, batch_size=256, log2_table_size=10, device="cpu", stop_patience=0)
COPY, SURFACE = "armature copy", "evaluated surface"


def choose(core, obj, count=3):
    spec = core("pose_sets").PoseSpec(count=count)
    return core("blender.follow_choice").choose_follow(obj, RESOLUTION, spec, poses=POSES,
                                                       size=SIZE), spec


def test_the_margin_keeps_the_copies_on_a_tie(core):
    better = core("blender.follow_choice").better

    def row(error, mismatch=0.01):
        return {"embedding_error": error, "hit_mismatch": mismatch}

    assert not better(row(1e-3), row(1e-3))                       # a tie keeps the copies
    assert not better(row(1e-3), row(1.4e-3))                     # within the margin
    assert better(row(1e-3), row(2e-3))
    assert not better(row(1e-3, 0.05), row(2e-3, 0.01))           # more hits missed
    assert not better(row(None), row(2e-3))


def test_a_thin_lattice_trains_and_renders_with_the_surface_binding(empty_scene, core,
                                                                    tmp_path):
    """The slab's lattice is fitted tightly: the binding's embedding error is a fraction of
    the copies'. Chosen where the dataset is made, it is recorded in the dataset header
    and the model file, and the model's evaluation and render captures follow it."""
    slab = thin_lattice_slab()
    choice, spec = choose(core, slab)
    copy, surface = choice.errors[COPY], choice.errors[SURFACE]
    print(choice.describe())
    assert choice.follow == SURFACE
    assert surface["embedding_error"] * 3 < copy["embedding_error"]
    steps = core("blender.steps")
    said = []
    captured = steps.training_capture(slab, RESOLUTION, spec, say=said.append)
    assert captured.corners_follow == SURFACE
    assert len(said) == 1 and said[0].startswith(f"corners follow: {SURFACE} (") and " s)" in \
        said[0]
    header = steps.variant_dataset(slab, captured, "proposed", tmp_path / "data", 64)
    assert header.corners_follow == SURFACE
    core("training.fit").fit_model(tmp_path / "data", "proposed", tmp_path / "m.vdnif", TINY)
    _, metadata = core("model.model_file").load_model(tmp_path / "m.vdnif")
    assert metadata.corners_follow == SURFACE
    reader = core("blender.pose_reader").PoseReader
    for evaluation in (True, False):
        again = steps.model_capture(slab, metadata, spec, evaluation=evaluation, count=1)
        assert again.corners_follow == SURFACE
        with_reader = reader(slab, again)
        try:
            assert with_reader.deformer.binding is not None
        finally:
            with_reader.close()


def test_an_armature_arm_keeps_the_copies(empty_scene, core):
    """The arm's copies are as good as the binding: kept. An old model file (no record)
    is evaluated with the copies, one that records the binding with the binding, whatever
    the arm itself would choose."""
    arm = core("blender.scenes").demo_scene("arm")
    choice, spec = choose(core, arm)
    print(choice.describe())
    assert choice.follow == COPY and set(choice.errors) == {COPY, SURFACE}
    steps = core("blender.steps")
    _, old = core("model.model_file").load_model(GOLDEN / "arm-train.vdnif")
    assert steps.model_capture(arm, old, spec, evaluation=True, count=1).corners_follow == COPY
    bound = dataclasses.replace(old, corners_follow=SURFACE)
    assert steps.model_capture(arm, bound, spec, evaluation=True,
                               count=1).corners_follow == SURFACE
    assert steps.model_capture(arm, bound, spec).corners_follow == SURFACE


def test_a_rig_only_the_surface_follows_is_not_measured(empty_scene, core):
    import artist_rigs

    obj, keywords = artist_rigs.build("driven_key")
    spec = core("pose_sets").PoseSpec(count=2, **keywords)
    choice = core("blender.follow_choice").choose_follow(obj, 8, spec)
    assert choice.follow == SURFACE and choice.errors == {}


def test_a_coarse_cage_under_a_subdivision_binds_to_the_subdivided_surface(empty_scene, core):
    """The box's 74-vertex cage misses the rounding its Subdivision adds between the
    vertices: the subdivided surface is measured closer by more than the margin and chosen,
    and a capture following it binds every corner to the subdivided mesh's vertices."""
    import artist_rigs
    import scene_builders as sb

    obj, keywords = artist_rigs.build("subdivision")
    spec = core("pose_sets").PoseSpec(count=4, **keywords)
    follow = core("blender.follow_choice")
    choice = follow.choose_follow(obj, 16, spec)
    subdivided = core("geometry.capture").SUBDIVIDED_SURFACE
    assert choice.follow == subdivided and set(choice.errors) == {SURFACE, subdivided}
    assert follow.better(choice.errors[subdivided], choice.errors[SURFACE])
    captured = core("blender.capture_scene").capture(obj, 8, spec, deform_corners=False,
                                                     follow=subdivided)
    deform = core("blender.deform")
    with deform.CornerDeformer(obj, captured.grid.corner_positions(),
                               captured.corners_follow) as deformer:
        assert deformer.binding.vertex_count == len(sb.evaluated_vertices(obj)) > len(
            obj.data.vertices)
