"""What the operators keep survives undoing a later edit. Blender's UI pushes an undo step
after an operator with the UNDO flag and after every edit in a panel, never for what a modal
operator writes later from its timer; headless Blender pushes none by itself. Here the steps
the UI would push are pushed by hand, so the operators' own steps are what is tested: a value
written without one belongs to no step, and undoing the next edit takes it away."""

import hashlib

import bpy
import pytest
from test_ui_workflow import SMALL, arm_scene, eager_model, modal_run, module


def ui(name, **properties):
    """Runs the operator ``vdnif.NAME`` as a click would, then pushes the undo step that
    Blender's UI pushes for an operator with the UNDO flag."""
    getattr(bpy.ops.vdnif, name)(**properties)
    cls = getattr(bpy.types, f"VDNIF_OT_{name}")
    if "UNDO" in getattr(cls, "bl_options", set()):
        bpy.ops.ed.undo_push(message=cls.bl_label)


def edit(name, value):
    """A later edit in the panel, with the step the UI pushes for it."""
    setattr(arm().vdnif, name, value)
    bpy.ops.ed.undo_push(message=name)


def arm():
    """The arm as it is now (an undo replaces every object: older references are dead)."""
    return bpy.data.objects["Arm"]


def kept():
    """What the arm keeps: its model's bytes and every setting the operators write."""
    settings = arm().vdnif
    storage = module("storage")
    packed = settings.get(storage.PACKED)
    return {"model": None if packed is None else hashlib.sha256(bytes(packed)).hexdigest(),
            **{name: getattr(settings, name) for name in (
                "model_info", "dataset_info", "dataset_dir", "metrics", "estimate_info",
                "resolution_info", "variant", "width", "depth", "steps", "resolution",
                "levels", "pe_bands")}}


def survives_a_later_undo(what):
    """Edits a setting (a step), undoes that edit: everything ``kept`` is as before it."""
    before = kept()
    assert before[what], f"the operator kept no {what}"
    edit("seed", arm().vdnif.seed + 1)
    bpy.ops.ed.undo()
    assert kept() == before
    return before


@pytest.fixture
def arm_ready(empty_scene):
    arm_scene()
    bpy.ops.ed.undo_push(message="Set up")            # the UI pushed the set-up's edits
    return arm()


def test_jobs_and_loaded_models_survive_undoing_a_later_edit(arm_ready, tmp_path):
    ui("generate_dataset")
    survives_a_later_undo("dataset_info")
    ui("train")
    trained = survives_a_later_undo("model")
    ui("evaluate")
    survives_a_later_undo("metrics")
    ui("estimate")
    survives_a_later_undo("estimate_info")
    eager = tmp_path / "eager.vdnif"
    eager_model(module("storage").model_path(arm()), eager)
    edit("width", 7)
    ui("load_model", filepath=str(eager))
    loaded = survives_a_later_undo("model")
    assert loaded["model"] == hashlib.sha256(eager.read_bytes()).hexdigest() != trained["model"]
    assert loaded["width"] == SMALL["width"], "the loaded model's settings were adopted"
    ui("apply_preset", preset="fast")
    survives_a_later_undo("model")


def test_a_result_kept_from_the_timer_survives_undoing_a_later_edit(arm_ready):
    """The modal path (Blender's timer ticks the job): training's model and the dataset made
    on the way, each stage with its own step."""
    result, _, _ = modal_run(module("operators.training").VDNIF_OT_train, "Arm")
    assert result == {"FINISHED"}
    after = survives_a_later_undo("model")
    assert after["dataset_info"] and after["model_info"]
    bpy.ops.ed.undo()                                  # the training's own step
    assert kept()["dataset_info"] == after["dataset_info"] and kept()["model"] is None
