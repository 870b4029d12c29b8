"""Blender files of the bounds cases, built in a fresh process (``build``): arrays before
the rig whose offset object moves or stays, a ball with one far loose vertex, UDIM planes.
Imports nothing of the core."""

import subprocess
import sys

BLEND_SCRIPT = r"""
import bpy, sys
out = sys.argv[-1]

def arrayed(offset_moves):
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    offset = bpy.data.objects.new("Offset", None)
    bpy.context.scene.collection.objects.link(offset)
    offset.location = (2.5, 0.0, 0.0)
    array = cube.modifiers.new("Array", "ARRAY")
    array.use_relative_offset, array.use_object_offset = False, True
    array.offset_object = offset
    lattice = bpy.data.objects.new("Lattice", bpy.data.lattices.new("Lattice"))
    bpy.context.scene.collection.objects.link(lattice)
    lattice.scale = (8.0, 3.0, 3.0)
    cube.modifiers.new("Lattice", "LATTICE").object = lattice
    offset_moves(offset)
    bpy.ops.wm.save_as_mainfile(filepath=f"{out}/array_{offset_moves.__name__}.blend")

def animated(offset):
    offset.keyframe_insert("location", frame=1)
    offset.location.x = 4.0
    offset.keyframe_insert("location", frame=20)

def on_bone(offset):
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    offset.parent = rig

def still(offset):
    pass

for moves in (animated, on_bone, still):
    arrayed(moves)

bpy.ops.wm.read_homefile(use_empty=True)   # a ball and one loose vertex 1,000 units away
bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0)
ball = bpy.context.active_object
ball.name = "Ball"
ball.data.vertices.add(1)
ball.data.vertices[-1].co = (1000.0, 0.0, 0.0)
bpy.ops.wm.save_as_mainfile(filepath=f"{out}/loose_vertex.blend")

import os                                   # a plane textured by a UDIM image of two tiles
import numpy as np

def udim_plane(name, moved):
    os.makedirs(f"{out}/{name}")
    for number, colour in ((1001, (1, 0, 0, 1)), (1002, (0, 0, 1, 1))):
        tile = bpy.data.images.new(f"t{number}", 4, 4)
        tile.pixels.foreach_set(np.tile(colour, 16).astype(np.float32))
        tile.filepath_raw, tile.file_format = f"{out}/{name}/tex.{number}.png", "PNG"
        tile.save()
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_plane_add()
    plane = bpy.context.active_object
    uv = plane.data.uv_layers.active.data
    for loop in plane.data.polygons[0].loop_indices[:moved]:
        uv[loop].uv.x += 1.0
    image = bpy.data.images.load(f"{out}/{name}/tex.1001.png")
    image.source, image.filepath = "TILED", f"{out}/{name}/tex.<UDIM>.png"
    image.name = "tex.<UDIM>.png"
    material = bpy.data.materials.new("Tiled")
    material.use_nodes = True
    texture = material.node_tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    material.node_tree.links.new(
        texture.outputs["Color"],
        material.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    plane.data.materials.append(material)
    bpy.ops.wm.save_as_mainfile(filepath=f"{out}/{name}.blend")

udim_plane("udim_both", 2)        # two corners moved right: the triangles straddle 1001, 1002
udim_plane("udim", 4)             # every corner in tile 1002, whose file is then missing
os.remove(f"{out}/udim/tex.1002.png")
"""


def build(folder):
    """Writes the files into ``folder``; returns {"blend:<name>": path}."""
    subprocess.run([sys.executable, "-c", BLEND_SCRIPT, str(folder)], check=True,
                   capture_output=True, timeout=120)
    return {f"blend:{path.stem}": path for path in folder.glob("*.blend")}
