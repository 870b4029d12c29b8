"""A flat slab in a lattice fitted tightly around it, as a user fits one: Blender holds the
lattice's deformation still outside its box, where the voxel corners above and below the
slab lie, so the copied lattice modifier leaves them behind while the slab bends. Shared by
the corner-follow tests and ``tools/follow_choice_table.py``."""

import bpy
import numpy as np
import scene_builders as sb


def thin_lattice_slab(cells=8, margin=1.1, points=3):
    """A slab ``cells`` x ``cells`` x 1 quads (one unit long) in a ``points``^3 lattice
    ``margin`` times its extent on every axis (thin like the slab); random poses move the
    lattice's points."""
    slab = sb.lattice_box((cells, cells, 1), 1.0 / cells, name="Slab")
    co = sb.mesh_vertices(slab)
    data = bpy.data.lattices.new("Fitted")
    data.points_u = data.points_v = data.points_w = points
    lattice = bpy.data.objects.new("Fitted", data)
    bpy.context.scene.collection.objects.link(lattice)
    lattice.location = 0.5 * (co.min(axis=0) + co.max(axis=0))
    rest = np.array([p.co for p in data.points])
    lattice.scale = margin * np.ptp(co, axis=0) / np.ptp(rest, axis=0)
    modifier = slab.modifiers.new("Lattice", "LATTICE")
    modifier.object = lattice
    bpy.context.view_layer.update()
    return slab
