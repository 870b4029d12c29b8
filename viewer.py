"""The UI's helpers that are not operators: the voxel preview object, rays of the 3D
Viewport's view, and the pass viewer: the kept view (module state, dropped by this module's
own load_post handler when another file is opened) and its float images. The operators,
panels and properties use it; the Blender adapters it needs stay in
``vdnif_addon/blender/``."""

import math

import bpy
import numpy as np

from .vdnif_addon.blender.capture_scene import capture
from .vdnif_addon.blender.deform import CornerDeformer
from .vdnif_addon.errors import VDNIFError
from .vdnif_addon.geometry.voxels import inverted_cells
from .vdnif_addon.inference.evaluation import view_images
from .vdnif_addon.inference.images import PASSES
from .vdnif_addon.settings import PoseSpec

# Albedo is shown sRGB-encoded (images.display), the other passes are data.
COLORSPACES = {"albedo": "sRGB"}
# (12, 2) the corners of a cell's edges, corner c = dx + 2 dy + 4 dz: pairs one bit apart.
CELL_EDGES = np.array([(c, c | bit) for bit in (1, 2, 4) for c in range(8) if not c & bit])

_view = {}      # the last rendered view: {"reference" | "predicted" | "error": {pass: image}}


def cell_edges(cell_corners):
    """(E, 2) unique corner index pairs of the edges of the cells ``cell_corners`` (N, 8)."""
    edges = np.sort(cell_corners[:, CELL_EDGES].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0)


def voxel_preview(obj, resolution, preview=None):
    """Voxelizes mesh object ``obj`` and shows its occupied cells, deformed as at the current
    frame, as a wireframe child object (``preview`` updated, or a new one). Returns the
    preview object and figures of the grid."""
    captured = capture(obj, resolution, PoseSpec(count=1), deform_corners=False)
    grid = captured.grid
    corners = grid.corner_positions()
    if captured.mode != "static":
        with CornerDeformer(obj, corners) as deformer:
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
               "inverted": int(inverted_cells(corners, grid.cell_corners).sum())}
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


def image_name(pass_name, source):
    """The image the viewer shows for a pass and a source."""
    return "VDNIF Error" if source == "error" else f"VDNIF {pass_name.title()}"


def set_view(reference, predicted, width, height, object_size):
    """Keeps the images of a rendered view (reference and predicted Passes) for the viewer:
    both passes on one distance scale, the error as heat maps; alpha is the hit mask."""
    shown = view_images(reference, predicted, height, width, object_size)
    alphas = {"reference": reference.hit, "predicted": predicted.hit,
              "error": np.ones(height * width, bool)}
    _view.clear()
    for source, images in shown.items():
        alpha = alphas[source].reshape(height, width, 1).astype(np.float32)
        _view[source] = {name: np.concatenate([image, alpha], axis=2)
                         for name, image in images.items()}


def viewed():
    """The kept view: {source: {pass: (H, W, 4) image}}, empty before the first render."""
    return _view


@bpy.app.handlers.persistent
def forget_view(*_):
    """Drops the kept view (a load_post handler: it belongs to the file it was made in)."""
    _view.clear()


def register():
    bpy.app.handlers.load_post.append(forget_view)


def unregister():
    bpy.app.handlers.load_post.remove(forget_view)


def image_editor(screen):
    """The screen's first Image Editor area, or None."""
    return next((a for a in (screen.areas if screen else ()) if a.type == "IMAGE_EDITOR"),
                None)


def show(context, viewer):
    """Writes the images of the viewer's pass and source from the kept view and shows the
    chosen one in an Image Editor of the screen, if there is one. Returns that image, or
    None when nothing was rendered yet."""
    if not _view:
        return None
    pass_name, source = viewer.pass_name, viewer.source
    shown = "reference" if source == "reference" else "predicted"
    images = {name: write_image(image_name(name, shown), _view[shown][name],
                                COLORSPACES.get(name, "Non-Color")) for name in PASSES}
    images["error"] = write_image(image_name(pass_name, "error"), _view["error"][pass_name],
                                  "Non-Color")
    image = images["error" if source == "error" else pass_name]
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
    elif tuple(image.size) != (width, height):
        image.scale(width, height)
    image.colorspace_settings.name = colorspace
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())
    image.update()
    return image
