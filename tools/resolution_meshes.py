"""Two meshes unlike the demo scenes, for the resolution study (``tools/resolution_table.py``),
built with bpy and written as OBJ files (the procedural rig is added when a command reads
them): a thin-walled open cup and a flat plate with a grid of holes. Both are thin
everywhere: their walls are a few hundredths of their size, under two voxels at the
default resolution.

    python tools/resolution_meshes.py --cup out/cup.obj --plate out/plate.obj

And, built in the open scene with its rig for ``tools/corners_follow_choice.py`` and the
corner-following tests (``tests/support/thin_lattice.py``), a flat slab in a lattice fitted
tightly around it. This module imports bpy and numpy, no copy of the core, so that a Blender
test may import it.
"""

import argparse
import math
import pathlib
import sys

import bpy  # isort: skip  (Blender's modules come with it)
import numpy as np

CUP = {"radius": 0.35, "height": 1.0, "wall": 0.035, "sides": 48, "rings": 24}
"""Open at the top, closed at the bottom; the wall is 3.5 % of the height."""
PLATE = {"length": 1.2, "width": 0.8, "thickness": 0.04, "cells": (60, 40),
         "holes": (5, 3), "hole_cells": 6}
"""A grid of square holes, hole_cells cells wide, spread evenly over the plate."""


def _reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _solid(name, vertices, faces, thickness):
    """A mesh object of ``vertices`` and ``faces`` thickened inward by ``thickness`` (the
    Solidify modifier, applied: rims close the open edges)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices, [], faces)
    mesh.validate()
    sheet = bpy.data.objects.new(f"{name} sheet", mesh)
    bpy.context.scene.collection.objects.link(sheet)
    solidify = sheet.modifiers.new("Solidify", "SOLIDIFY")
    solidify.thickness, solidify.offset, solidify.use_even_offset = thickness, -1.0, True
    solidify.use_rim = True
    depsgraph = bpy.context.evaluated_depsgraph_get()
    solid = bpy.data.meshes.new_from_object(sheet.evaluated_get(depsgraph))
    bpy.data.objects.remove(sheet)
    obj = bpy.data.objects.new(name, solid)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def cup(path, radius=CUP["radius"], height=CUP["height"], wall=CUP["wall"],
        sides=CUP["sides"], rings=CUP["rings"]):
    """Writes the open cup, standing on z = 0, as an OBJ file at ``path``."""
    _reset()
    vertices = [(0.0, 0.0, 0.0)]
    for ring in range(rings + 1):
        z = height * ring / rings
        vertices += [(radius * math.cos(2 * math.pi * k / sides),
                      radius * math.sin(2 * math.pi * k / sides), z) for k in range(sides)]

    def at(ring, k):
        return 1 + ring * sides + k % sides

    # Normals outward (the solid grows inward from the outer surface).
    faces = [(0, at(0, k + 1), at(0, k)) for k in range(sides)]
    faces += [(at(r, k), at(r, k + 1), at(r + 1, k + 1), at(r + 1, k))
              for r in range(rings) for k in range(sides)]
    _export(_solid("Cup", vertices, faces, wall), path)


def plate(path, length=PLATE["length"], width=PLATE["width"], thickness=PLATE["thickness"],
          cells=PLATE["cells"], holes=PLATE["holes"], hole_cells=PLATE["hole_cells"]):
    """Writes the plate with holes, centred on the origin in the xy plane, as an OBJ file."""
    _reset()
    nx, ny = cells
    vertices = [(length * (i / nx - 0.5), width * (j / ny - 0.5), thickness / 2)
                for j in range(ny + 1) for i in range(nx + 1)]

    def hole_cells_of(count, total):
        gap = (total - count * hole_cells) // (count + 1)
        starts = [gap + k * (gap + hole_cells) for k in range(count)]
        return {s + c for s in starts for c in range(hole_cells)}

    open_x, open_y = hole_cells_of(holes[0], nx), hole_cells_of(holes[1], ny)
    faces = [(j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1,
              (j + 1) * (nx + 1) + i)
             for j in range(ny) for i in range(nx) if not (i in open_x and j in open_y)]
    _export(_solid("Plate", vertices, faces, thickness), path)


def thin_lattice_slab(cells=8, margin=1.1, points=3):
    """A slab ``cells`` x ``cells`` x 1 quads (one unit long, one cell thick; every vertex on
    the grid of its cells) in a ``points``^3 lattice ``margin`` times its extent on every
    axis (thin like the slab), added to the open scene; random poses move the lattice's
    points. Blender holds a lattice's deformation still outside its box, where the voxel
    corners above and below the slab lie, so the copied lattice modifier leaves them behind
    while the slab bends."""
    step = 1.0 / cells
    vertices = [(i * step, j * step, step) for j in range(cells + 1) for i in range(cells + 1)]
    faces = [(j * (cells + 1) + i, j * (cells + 1) + i + 1, (j + 1) * (cells + 1) + i + 1,
              (j + 1) * (cells + 1) + i) for j in range(cells) for i in range(cells)]
    slab = _solid("Slab", vertices, faces, step)           # from z = step down to 0
    co = np.array([vertex.co for vertex in slab.data.vertices])
    data = bpy.data.lattices.new("Fitted")
    data.points_u = data.points_v = data.points_w = points
    lattice = bpy.data.objects.new("Fitted", data)
    bpy.context.scene.collection.objects.link(lattice)
    lattice.location = 0.5 * (co.min(axis=0) + co.max(axis=0))
    rest = np.array([point.co for point in data.points])
    lattice.scale = margin * np.ptp(co, axis=0) / np.ptp(rest, axis=0)
    modifier = slab.modifiers.new("Lattice", "LATTICE")
    modifier.object = lattice
    bpy.context.view_layer.objects.active = slab
    bpy.context.view_layer.update()
    return slab


def _export(obj, path):
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for other in bpy.data.objects:
        other.select_set(other is obj)
    bpy.ops.wm.obj_export(filepath=str(path), export_selected_objects=True,
                          export_materials=False, export_uv=False)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cup", type=pathlib.Path, help="write the cup here (.obj)")
    parser.add_argument("--plate", type=pathlib.Path, help="write the plate here (.obj)")
    args = parser.parse_args(argv)
    if args.cup:
        cup(args.cup)
        print(f"wrote {args.cup}")
    if args.plate:
        plate(args.plate)
        print(f"wrote {args.plate}")


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:])
