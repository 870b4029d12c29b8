"""The side-by-side study trains a missing model as the product would: its corners follow
as the choice measured for it says (``steps.training_capture``), recorded in the model file
that its timing then follows (``steps.model_capture``). A slab in a tightly fitted lattice
follows the evaluated surface; the arm keeps the copied armature."""

import importlib

from conftest import EXTENSION_MODULE
from thin_lattice import thin_lattice_slab


def core(name):
    return importlib.import_module(f"{EXTENSION_MODULE}.vdnif_addon.{name}")


def trained_follow(monkeypatch, tmp_path, scene, build=None):
    """How the corners of the quick model trained for ``scene`` follow (built by ``build``
    where given), at resolution 16."""
    study = core("studies.side_by_side")
    quick = study.SIZES["quick"]
    monkeypatch.setitem(study.SIZES, "quick", dict(
        quick, resolution=16, overrides=dict(quick["overrides"], steps=2)))
    if build is not None:
        monkeypatch.setattr(study, "load_side_by_side_scene", lambda name: build())
    path = study.recipe_model(scene, tmp_path, device="cpu", quick=True)
    return core("model.model_file").load_model(path)[1].corners_follow


def test_a_thin_lattice_model_follows_the_surface(empty_scene, monkeypatch, tmp_path):
    assert trained_follow(monkeypatch, tmp_path, "lattice",
                          thin_lattice_slab) == "evaluated surface"


def test_the_arm_model_keeps_the_copies(empty_scene, monkeypatch, tmp_path):
    assert trained_follow(monkeypatch, tmp_path, "arm") == "armature copy"


def test_a_pose_bound_to_the_cage_is_timed_with_the_cage_evaluated(empty_scene):
    """A rig with a Subdivision after its armature: the corners follow its cage, whose
    evaluation is the neural pose's Blender work (the subdivided mesh is the classical
    paths')."""
    import artist_rigs

    obj, keywords = artist_rigs.build("subdivision")
    poses = core("blender.poses")
    captured = core("blender.capture_scene").capture(
        obj, 8, poses.evaluation_spec(poses.PoseSpec(count=2, **keywords)),
        deform_corners=False)
    assert captured.corners_follow == "evaluated surface"
    result = core("studies.side_by_side").compare_paths(obj, captured, None, 8, 8, repeats=1)
    records = result["runs"][0]["poses"]
    assert len(records) == 2
    for record in records:
        assert record["neural_evaluate_s"] > 0
        assert record["neural_pose_s"] >= record["neural_evaluate_s"]
