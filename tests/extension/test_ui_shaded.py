"""The Shaded toggle in the panel's workflow on the trained arm: on alone, Render Passes
writes Shaded (not AO, not Shadow) into the frame's EXR and fills the viewer's Shaded images,
and Evaluate reports the shaded image's figures."""

import json
import math

import bpy
import numpy as np
from blender_exr import pass_names
from test_ui_workflow import (
    module,
    pixels,
    session,  # noqa: F401  (the trained arm, saved)
)


def test_shaded_alone_is_written_shown_and_evaluated(session):  # noqa: F811
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    obj.vdnif.pass_ao = obj.vdnif.pass_shadow = False
    obj.vdnif.pass_shaded, obj.vdnif.ao_samples = True, 2
    bpy.context.scene.vdnif_viewer.pass_name = "shaded"
    bpy.ops.vdnif.render_passes()
    folder = module("storage").passes_folder(obj)
    frame = f"{bpy.context.scene.frame_current:04d}"
    for prefix in ("", "true-"):
        names = pass_names(folder / f"{prefix}passes.{frame}.exr")
        assert "Shaded" in names and not {"AO", "Shadow"} & names, prefix
        assert (folder / f"{prefix}shaded.{frame}.png").is_file()
    assert module("viewer").viewed("shaded")
    for source in ("reference", "predicted", "error"):
        image = pixels(f"VDNIF Shaded ({source})")
        assert image.shape == (24, 32, 4) and np.isfinite(image).all(), source
    predicted = pixels("VDNIF Shaded (predicted)")
    hit = predicted[..., 3] > 0.5
    assert np.ptp(predicted[..., :3][hit]) > 0.1, "lit and unlit sides of the arm"
    bpy.ops.vdnif.evaluate()
    report = json.loads(obj.vdnif.metrics)
    for reference in ("vs_true", "vs_embedded"):
        for key in ("shaded_psnr", "shaded_visible_rate", "shadow_false_lit_rate_cast",
                    "shadow_false_shadow_rate_cast"):
            value = report[reference][key]
            assert value is not None and math.isfinite(value), (reference, key)
    assert report["secondary"]["terminator_band"] == module(
        "vdnif_addon.settings").TERMINATOR_BAND
