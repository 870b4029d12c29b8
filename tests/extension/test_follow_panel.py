"""Generate Dataset chooses how the voxel corners follow the mesh in a worker (the main
thread reads each capture and pose it asks for), says the choice with its seconds, and
records it in the dataset; Train keeps it in the model, whose info line in the panel shows
it."""

import re

import bpy
from test_ui_panels import draw_all, texts
from test_ui_workflow import SMALL, modal_run, module
from thin_lattice import thin_lattice_slab

SURFACE = "evaluated surface"


def test_the_panel_chooses_records_and_shows_how_the_corners_follow(empty_scene, extension):
    slab = thin_lattice_slab()
    bpy.context.view_layer.objects.active = slab
    for name, value in dict(SMALL, resolution=16, pose_count=3, steps=3).items():
        setattr(slab.vdnif, name, value)
    generate = module("operators.scene").VDNIF_OT_generate_dataset
    result, status, reports = modal_run(generate, "Slab")
    assert result == {"FINISHED"}, reports
    assert any(re.search(r"corners: [01]/2 ways", text) for text in status)
    assert re.search(rf"corners follow: {SURFACE} \(chosen in [0-9.]+ s\)", reports[-1][1])
    storage = module("storage")
    read_dataset = module("vdnif_addon.training.dataset").read_dataset
    assert read_dataset(storage.dataset_folder(slab))[0].header.corners_follow == SURFACE
    assert not [o for o in bpy.data.objects if "VDNIF" in o.name]     # helpers removed
    bpy.ops.vdnif.train()
    assert slab.vdnif.parsed("model_info")["corners_follow"] == SURFACE
    assert f"corners follow: {SURFACE}" in texts(draw_all(extension))
