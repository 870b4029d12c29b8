"""Reads a multilayer EXR back the way a compositing artist would: Blender loads it
(``bpy.data.images.load``), an Image node of the compositor lists its layer and passes, and
each pass goes through the compositor into the render result, saved as a plain 32-bit EXR
that Blender loads again to read its pixels. Nothing here parses EXR itself."""

import pathlib
import tempfile

import bpy
import numpy as np


def read_multilayer(path, width, height):
    """(the first layer's name, {pass socket name: (H, W, 4) float32, row 0 at the top}) of the
    ``width`` x ``height`` multilayer EXR ``path`` as Blender's compositor reads it (Blender
    gives no size for a multilayer image before it is shown); a one-channel pass comes back
    in R, G and B, a pass without alpha with alpha 1. Runs in the current scene (its
    compositor and render settings are replaced)."""
    image = bpy.data.images.load(str(path), check_existing=False)
    scene = bpy.context.scene
    scene.use_nodes = True
    tree = scene.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("CompositorNodeImage")
    node.image = image
    assert image.type == "MULTILAYER", image.type
    layer = node.layer
    composite = tree.nodes.new("CompositorNodeComposite")
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth, settings.color_mode = "OPEN_EXR", "32", "RGBA"
    scene.view_settings.view_transform = "Raw"      # values as they are, no display curve
    read = {}
    with tempfile.TemporaryDirectory(prefix="vdnif-exr-") as folder:
        for socket in node.outputs:
            if socket.name == "Alpha":                # Combined's alpha: read in Combined
                continue
            scene.render.resolution_x, scene.render.resolution_y = width, height
            scene.render.resolution_percentage = 100
            tree.links.new(socket, composite.inputs["Image"])
            bpy.ops.render.render()
            saved = pathlib.Path(folder) / f"{socket.name}.exr"
            bpy.data.images["Render Result"].save_render(str(saved), scene=scene)
            result = bpy.data.images.load(str(saved), check_existing=False)
            width, height = result.size
            pixels = np.empty(width * height * 4, np.float32)
            result.pixels.foreach_get(pixels)
            read[socket.name] = pixels.reshape(height, width, 4)[::-1]
            bpy.data.images.remove(result)
    bpy.data.images.remove(image)
    return layer, read


def pass_names(path):
    """The passes Blender's compositor offers for the multilayer EXR ``path``: the outputs of
    an Image node that opens it (Combined's alpha apart), without rendering anything. Runs in
    the current scene (its compositor is replaced)."""
    image = bpy.data.images.load(str(path), check_existing=False)
    scene = bpy.context.scene
    scene.use_nodes = True
    tree = scene.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("CompositorNodeImage")
    node.image = image
    assert image.type == "MULTILAYER", image.type
    names = {socket.name for socket in node.outputs if socket.name != "Alpha"}
    tree.nodes.clear()
    bpy.data.images.remove(image)
    return names
