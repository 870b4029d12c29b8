"""The pass viewer's images and the loss plot come back with their pixels when the .blend is
opened again (saved as EXR beside it, read back on load), and choosing a pass shows its
image without an error from Blender (an update callback must return None)."""

import bpy
import numpy as np
from conftest import EXTENSION_MODULE
from test_ui_workflow import (
    PASS_IMAGES,
    module,
    pixels,
    session,  # noqa: F401  (the trained arm, saved)
)

PLOT = "VDNIF Training (Arm)"


def open_blend(path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    return obj


def image_editor():
    """The screen's first area other than the 3D Viewport, made an Image Editor."""
    editor = next(a for a in bpy.context.screen.areas if a.type != "VIEW_3D")
    editor.type = "IMAGE_EDITOR"
    return editor


def test_pass_images_and_the_loss_plot_come_back_on_reopen(session, extension):  # noqa: F811
    """Render, save, reopen: every image the panel names holds the pixels it held (the
    colour-managed albedo and plot too), in its colour space, and the viewer shows them
    before anything is rendered again."""
    from test_ui_panels import draw_all, texts

    obj = open_blend(session["blend"])
    assert bpy.data.images[PLOT].size[0] > 0, "Train drew the loss plot"
    bpy.context.scene.vdnif_viewer.pass_name = "ao"
    obj.vdnif.pass_ao = obj.vdnif.pass_shadow = True
    obj.vdnif.ao_samples = 4
    bpy.ops.vdnif.render_passes()
    names = (*PASS_IMAGES, PLOT, *(f"VDNIF {title} ({source})" for title in ("AO", "Shadow")
                                   for source in ("predicted", "reference", "error")))
    before = {name: pixels(name) for name in names}
    spaces = {name: bpy.data.images[name].colorspace_settings.name for name in names}
    assert len(set(spaces.values())) == 2, "sRGB and Non-Color images"
    assert all(np.ptp(image) > 0 for image in before.values()), "blank images prove nothing"
    bpy.ops.wm.save_mainfile()

    obj = open_blend(session["blend"])
    assert not module("viewer").viewed(), "nothing was rendered in the reopened file"
    for name, image in before.items():
        np.testing.assert_array_equal(pixels(name), image, err_msg=name)
        assert bpy.data.images[name].colorspace_settings.name == spaces[name], name
    viewer, editor = bpy.context.scene.vdnif_viewer, image_editor()
    assert viewer.pass_name == "ao"
    viewer.source = "error"
    assert editor.spaces.active.image.name == "VDNIF AO (error)"
    viewer.pass_name = "albedo"
    assert editor.spaces.active.image.name == "VDNIF DiffCol (error)"
    shown = texts(draw_all(extension))
    assert "Image: VDNIF DiffCol (error)" in shown and f"Loss plot: image '{PLOT}'" in shown


def test_an_older_view_and_a_lost_file_are_not_reopened(session):  # noqa: F811
    """A render without AO leaves the AO images of an earlier one behind: they are not
    reopened as if they were this view's. An image whose file is gone is removed on reopen,
    so the panel never names an empty image."""
    obj = open_blend(session["blend"])
    viewer = bpy.context.scene.vdnif_viewer
    viewer.pass_name = "shadow"
    obj.vdnif.pass_shadow = True
    bpy.ops.vdnif.render_passes()
    viewer.pass_name = "normal"
    obj.vdnif.pass_ao = obj.vdnif.pass_shadow = False
    bpy.ops.vdnif.render_passes()                         # no AO, no shadow this time
    bpy.ops.wm.save_mainfile()
    plot = bpy.data.images[PLOT]
    kept = module("viewer").KEPT_FILE
    (session["blend"].parent / plot[kept].removeprefix("//")).unlink()

    open_blend(session["blend"])
    assert PLOT not in bpy.data.images
    assert "VDNIF Normal (predicted)" in bpy.data.images
    viewer = bpy.context.scene.vdnif_viewer
    viewer.pass_name = "shadow"
    assert not module("viewer").available("shadow", "predicted")
    assert "VDNIF Shadow (predicted)" not in bpy.data.images or (
        kept not in bpy.data.images["VDNIF Shadow (predicted)"])


def test_choosing_a_pass_returns_none_to_blender_and_shows_it(session, capfd):  # noqa: F811
    """Blender prints 'ValueError: the return value must be None' for an update callback
    that returns something: the viewer's callbacks return None and still show the image."""
    open_blend(session["blend"])
    bpy.ops.vdnif.render_passes()
    editor = image_editor()
    viewer = bpy.context.scene.vdnif_viewer
    declared = module("properties").VDNIFViewer.__annotations__
    capfd.readouterr()
    for name, value in (("source", "reference"), ("pass_name", "distance")):
        setattr(viewer, name, value)
        assert declared[name].keywords["update"](viewer, bpy.context) is None
    assert editor.spaces.active.image.name == "VDNIF Depth (reference)"
    printed = capfd.readouterr()
    assert "must be None" not in printed.out + printed.err
    assert EXTENSION_MODULE in bpy.context.preferences.addons
