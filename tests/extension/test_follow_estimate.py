"""The panel's estimate and Voxelize follow the corners' way that training will: the
estimate measures the choice (in a worker) and keeps it with its figures, and Train's
dataset, made for the same settings, takes it from there instead of measuring it again;
Voxelize previews the corners so. A slab in a tightly fitted lattice follows the evaluated
surface; the arm keeps the copied armature."""

import bpy
from test_ui_workflow import SMALL, arm_scene, module
from thin_lattice import thin_lattice_slab

COPY, SURFACE = "armature copy", "evaluated surface"


def counted_choices(monkeypatch):
    """The list that grows by one at each measured choice."""
    follow_choice = module("vdnif_addon.blender.follow_choice")
    measured, real = [], follow_choice.choose_follow
    monkeypatch.setattr(follow_choice, "choose_follow",
                        lambda *args, **kwargs: measured.append(1) or real(*args, **kwargs))
    return measured


def test_a_thin_lattice_is_estimated_trained_and_previewed_with_the_binding(
        empty_scene, extension, monkeypatch):
    slab = thin_lattice_slab()
    bpy.context.view_layer.objects.active = slab
    for name, value in dict(SMALL, resolution=16, pose_count=3, steps=3).items():
        setattr(slab.vdnif, name, value)
    measured = counted_choices(monkeypatch)
    bpy.ops.vdnif.estimate()
    kept = slab.vdnif.parsed("estimate_info")["corners_follow"]
    assert kept["follow"] == SURFACE and set(kept["errors"]) == {COPY, SURFACE}
    assert measured == [1]
    bpy.ops.vdnif.train()
    assert measured == [1], "the dataset of the estimated settings takes the estimate's choice"
    read_dataset = module("vdnif_addon.training.dataset").read_dataset
    folder = module("storage").dataset_folder(slab)
    assert read_dataset(folder)[0].header.corners_follow == SURFACE
    assert slab.vdnif.parsed("model_info")["corners_follow"] == SURFACE
    bpy.ops.vdnif.voxelize()
    assert slab.vdnif.voxel_info.endswith(f"corners follow: {SURFACE}")


def test_the_arm_is_estimated_and_previewed_with_the_copies(empty_scene, extension):
    arm = arm_scene()
    bpy.ops.vdnif.estimate()
    assert arm.vdnif.parsed("estimate_info")["corners_follow"]["follow"] == COPY
    bpy.ops.vdnif.voxelize()
    assert arm.vdnif.voxel_info.endswith(f"corners follow: {COPY}")
