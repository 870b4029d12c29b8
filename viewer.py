"""The UI's helpers that are not operators: the voxel preview object, rays of the 3D
Viewport's view, and the pass viewer: the kept view (module state, dropped by this module's
own load_post handler when another file is opened) and its float images, saved as EXR files
beside the .blend and read back by another load_post handler when it is opened. The operators,
panels and properties use it; the Blender adapters it needs stay in
``vdnif_addon/blender/``."""

import math
import pathlib

import bpy
import numpy as np

from .vdnif_addon.blender.capture_scene import capture
from .vdnif_addon.blender.deform import CornerDeformer
from .vdnif_addon.errors import VDNIFError
from .vdnif_addon.geometry.voxels import inverted_cells
from .vdnif_addon.inference.evaluation import secondary_view_images, view_images
from .vdnif_addon.inference.images import PASSES
from .vdnif_addon.passes import (
    COMPOSITOR_SOURCES,
    SECONDARY_COMPOSITOR,
    SHADED_COMPOSITOR,
    SHADED_PASS,
    TOGGLED_PASSES,
)
from .vdnif_addon.pose_sets import PoseSpec

# Albedo and the shaded image are shown sRGB-encoded (images.display, images.shaded_display),
# the other passes are data.
COLORSPACES = {"albedo": "sRGB", SHADED_PASS: "sRGB"}
PASS_TITLES = {**{field: name for name, field in COMPOSITOR_SOURCES.items()},
               **{field: name for name, field in SECONDARY_COMPOSITOR.items()},
               SHADED_PASS: next(iter(SHADED_COMPOSITOR))}
"""The title of each pass in the images' names: its name in the multilayer EXR."""
SHOWN = (*PASSES, *TOGGLED_PASSES)
"""The passes the viewer offers: AO, shadow and shaded once a render cast their rays (their
toggles, ``operators.passes.secondary_settings``)."""
# (12, 2) the corners of a cell's edges, corner c = dx + 2 dy + 4 dz: pairs one bit apart.
CELL_EDGES = np.array([(c, c | bit) for bit in (1, 2, 4) for c in range(8) if not c & bit])

_view = {}      # the last rendered view: {"reference" | "predicted" | "error": {pass: image}}
KEPT_FILE = "vdnif_file"
"""The ID property of a VDNIF image naming the EXR its pixels are saved in (``keep``): a .blend
keeps a generated image's name and settings, never its pixels, so ``restore_images`` reads
them back from that file when the .blend is opened."""


def cell_edges(cell_corners):
    """(E, 2) unique corner index pairs of the edges of the cells ``cell_corners`` (N, 8)."""
    edges = np.sort(cell_corners[:, CELL_EDGES].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0)


def voxel_preview(obj, resolution, preview=None, spec=PoseSpec()):
    """Voxelizes mesh object ``obj`` and shows its occupied cells, deformed as at the current
    frame, as a wireframe child object (``preview`` updated, or a new one): the corners
    follow as a training on the poses of ``spec`` would have them (``steps.training_follow``,
    measured here: it renders, with PyTorch). Returns the preview object and figures of
    the grid."""
    from .vdnif_addon.blender.steps import training_follow

    follow = training_follow(obj, resolution, spec)
    captured = capture(obj, resolution, PoseSpec(count=1), deform_corners=False, follow=follow)
    grid = captured.grid
    corners = grid.corner_positions()
    if captured.mode != "static":
        with CornerDeformer(obj, corners, captured.corners_follow) as deformer:
            corners = deformer.deformed()
    edges = cell_edges(grid.cell_corners)
    preview = preview if preview is not None else _new_preview(obj)
    mesh = preview.data
    mesh.clear_geometry()
    mesh.vertices.add(len(corners))
    mesh.vertices.foreach_set("co", corners.astype(np.float32).ravel())
    mesh.edges.add(len(edges))
    mesh.edges.foreach_set("vertices", edges.astype(np.int32).ravel())
    mesh.update()
    figures = {"dims": grid.dims.tolist(), "cells": int(len(grid.cells)),
               "inverted": int(inverted_cells(corners, grid.cell_corners).sum()),
               "corners_follow": captured.corners_follow}
    return preview, figures


def _new_preview(obj):
    name = f"{obj.name} VDNIF Voxels"
    preview = bpy.data.objects.new(name, bpy.data.meshes.new(name))
    collections = obj.users_collection or (bpy.context.scene.collection,)
    collections[0].objects.link(preview)
    preview.parent = obj                  # the corners are in obj's local space
    preview.display_type = "WIRE"
    preview.hide_render = preview.hide_select = True
    return preview


def viewport_view(region_3d):
    """(world matrix (4, 4), horizontal field of view in degrees) of a perspective 3D
    Viewport view (its RegionView3D): the pinhole ``neural.view_rays`` renders."""
    if region_3d is None:
        raise VDNIFError("no 3D Viewport to render from: render through the camera instead")
    if not region_3d.is_perspective:
        raise VDNIFError("the 3D Viewport is orthographic: switch it to perspective "
                         "(Numpad 5) or render through the camera")
    projection = np.array(region_3d.window_matrix, np.float64)
    fov = math.degrees(2 * math.atan(1 / projection[0, 0]))
    return np.array(region_3d.view_matrix.inverted(), np.float64), fov


def render_size(scene, settings):
    """(width, height) of the object's renders (``settings``: its ``vdnif``): the scene's
    output resolution scaled by its percentage as Blender computes it, or the panel's width
    and height where Scene Output Size is off."""
    if not settings.use_scene_size:
        return settings.image_width, settings.image_height
    render = scene.render
    percent = render.resolution_percentage
    return (max(1, render.resolution_x * percent // 100),
            max(1, render.resolution_y * percent // 100))


def secondary_names(settings):
    """The passes beyond the primary ones (``passes.TOGGLED_PASSES``) whose toggles are on
    in the object's ``settings``: what the renders write (``passes.cast_passes``: the rays
    they cast)."""
    return tuple(name for name in TOGGLED_PASSES if getattr(settings, f"pass_{name}"))


def image_name(pass_name, source):
    """The image of one pass and source, e.g. "VDNIF Depth (predicted)": each its own, so
    the reference, the prediction and the error of every pass stay side by side."""
    return f"VDNIF {PASS_TITLES[pass_name]} ({source})"


def set_view(reference, predicted, width, height, object_size, secondary=None, folder=None,
             shaded=None):
    """Keeps the images of a rendered view (reference and predicted Passes; with
    ``secondary``, {"true", "predicted": SecondaryPasses}, the AO and shadow passes too, and
    the shaded image with ``shaded``, {"true", "predicted": (R, 3)}) for
    the viewer and writes each into its own float image: both passes on one distance scale,
    the error as heat maps; alpha is the hit mask (the error images are opaque). With a
    ``folder``, each image is saved there too (``keep``), so it comes back when the .blend
    is opened again."""
    shown = view_images(reference, predicted, height, width, object_size)
    if secondary is not None:
        more = secondary_view_images(secondary["true"], secondary["predicted"], height, width,
                                     shaded)
        for source, images in more.items():
            shown[source].update(images)
    alphas = {"reference": reference.hit, "predicted": predicted.hit,
              "error": np.ones(height * width, bool)}
    _view.clear()
    for source, images in shown.items():
        alpha = alphas[source].reshape(height, width, 1).astype(np.float32)
        _view[source] = {name: np.concatenate([image, alpha], axis=2)
                         for name, image in images.items()}
        for name in images:
            colorspace = "Non-Color" if source == "error" else COLORSPACES.get(name, "Non-Color")
            image = write_image(image_name(name, source), _view[source][name], colorspace)
            if folder is not None:
                keep(image, _view[source][name], pathlib.Path(folder) / f"{name}-{source}.exr")
    for name in SHOWN:           # images of an older view (AO, shadow) are not reopened
        for source in _view:
            image = bpy.data.images.get(image_name(name, source))
            if name not in _view[source] and image is not None and KEPT_FILE in image:
                del image[KEPT_FILE]
                image.use_fake_user = False


def write_files(obj, result, slots, width, height, frame, secondary_names=TOGGLED_PASSES):
    """Writes the predicted and the reference passes of a render (``neural.RenderResult`` of
    world rays, its material pass in used-slot indices mapped by ``slots``), with its AO,
    shadow and shaded passes ``secondary_names`` when it has them, into the object's passes
    folder as the render command does: PNG previews (one distance scale for both) and one
    multilayer EXR each for ``frame``, AO, Shadow and Shaded in it. Returns the predicted
    EXR's path."""
    from . import storage
    from .vdnif_addon.blender.steps import DistanceScale, write_passes
    from .vdnif_addon.inference.evaluation import world_distances

    folder = storage.passes_folder(obj)
    scale = DistanceScale()
    scale(*(world_distances(p, result.world_scale) for p in (result.predicted, result.true)))
    secondary, shaded = result.secondary or {}, result.shaded or {}
    written = None
    for name, prefix in (("true", "true-"), ("predicted", "")):
        written = write_passes(folder, getattr(result, name), height, width,
                               result.world_scale, prefix=prefix, slots=slots, frame=frame,
                               world_matrix=result.matrix_world,
                               secondary=secondary.get(name),
                               secondary_names=secondary_names, scale=scale,
                               shaded=shaded.get(name))
    return written[-1]


def viewed(pass_name=None):
    """The kept view: {source: {pass: (H, W, 4) image}}, empty before the first render, or
    before one with ``pass_name`` (AO and shadow are rendered only while their toggles are
    on)."""
    if pass_name is not None and pass_name not in _view.get("predicted", {}):
        return {}
    return _view


@bpy.app.handlers.persistent
def forget_view(*_):
    """Drops the kept view (a load_post handler: it belongs to the file it was made in)."""
    _view.clear()


def keep(image, rgba, path):
    """Saves ``rgba`` (H, W, 4), what ``image`` holds, as the EXR ``path`` (exact floats, no
    colour conversion) and names it in the image, which the .blend then keeps even while no
    Image Editor shows it."""
    from . import storage
    from .vdnif_addon.blender.image_io import save_image
    from .vdnif_addon.safe_io import claim_folder

    claim_folder(pathlib.Path(path).parent, "images folder")   # VDNIF's own: rewritable
    save_image(path, rgba)
    image[KEPT_FILE] = storage.portable(path)
    image.use_fake_user = True


@bpy.app.handlers.persistent
def restore_images(*_):
    """load_post: fills every image saved with ``keep`` from its EXR again. One whose file
    is gone is removed: the panel would name an empty image."""
    from .vdnif_addon.blender.image_io import load_image

    for image in list(bpy.data.images):
        path = image.get(KEPT_FILE)
        if path is None:
            continue
        try:
            rgba = load_image(bpy.path.abspath(path))
        except OSError as exc:
            print(f"vdnif: image '{image.name}' is not restored: {exc}")
            bpy.data.images.remove(image)
            continue
        write_image(image.name, rgba, image.colorspace_settings.name)


def register():
    bpy.app.handlers.load_post.append(forget_view)
    bpy.app.handlers.load_post.append(restore_images)


def unregister():
    bpy.app.handlers.load_post.remove(restore_images)
    bpy.app.handlers.load_post.remove(forget_view)


def image_editor(screen):
    """The screen's first Image Editor area, or None."""
    return next((a for a in (screen.areas if screen else ()) if a.type == "IMAGE_EDITOR"),
                None)


def available(pass_name, source):
    """Whether a pass and source has an image to show: rendered since the .blend was opened,
    or, before any render, restored with it (``restore_images``)."""
    if viewed(pass_name):
        return True
    image = bpy.data.images.get(image_name(pass_name, source))
    return not _view and image is not None and KEPT_FILE in image


def show(context, viewer):
    """Shows the image of the viewer's pass and source in the screen's first Image Editor, if
    there is one. Returns that image, or None when that pass was not rendered in this file
    yet (``available``)."""
    if not available(viewer.pass_name, viewer.source):
        return None
    name = image_name(viewer.pass_name, viewer.source)
    image = bpy.data.images.get(name)
    if image is None:                                      # the user deleted it: again
        source = viewer.source
        colorspace = "Non-Color" if source == "error" else COLORSPACES.get(
            viewer.pass_name, "Non-Color")
        image = write_image(name, _view[source][viewer.pass_name], colorspace)
    editor = image_editor(context.screen)
    if editor is not None:
        editor.spaces.active.image = image
    return image


def choice_changed(viewer, context):
    """The update of the pass viewer's pass and source: shows that image. Blender takes an
    update callback's return value as an error unless it is None."""
    show(context, viewer)


def training_image_name(obj):
    """The image of an object's loss plot."""
    return f"VDNIF Training ({obj.name})"


def show_training(context, obj, history):
    """Draws the loss plot of training's progress records ``history`` (``history.plot``) into
    the object's training image (saved beside the .blend too: ``keep``) and shows it in the
    screen's first Image Editor, if there is one. Returns the image."""
    from . import storage
    from .vdnif_addon.training.history import plot

    rgb = plot(history)
    rgba = np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], axis=2)
    image = write_image(training_image_name(obj), rgba, "sRGB")
    try:
        keep(image, rgba, storage.images_folder(obj) / "training.exr")
    except OSError as exc:      # the plot only: the model is kept all the same
        print(f"vdnif: '{obj.name}': the loss plot is not saved with the .blend: {exc}")
    editor = image_editor(context.screen)
    if editor is not None:
        editor.spaces.active.image = image
    return image


def write_image(name, rgba, colorspace):
    """The float image ``name`` holding ``rgba`` (H, W, 4), row 0 at the top."""
    height, width = rgba.shape[:2]
    image = bpy.data.images.get(name)
    if image is None:
        image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    # Setting a generated image's colour space (even to the one it has) or its generated
    # size makes its pixels again, blank, at the generated size: both before the pixels.
    if image.colorspace_settings.name != colorspace:
        image.colorspace_settings.name = colorspace
    if tuple(image.size) != (width, height):
        if image.source == "GENERATED":
            image.generated_width, image.generated_height = width, height
        else:
            image.scale(width, height)
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())
    image.update()
    return image
