"""Small scenes for tests whose answer is known independently of the code under test."""

import bpy
import numpy as np


def lattice_box(counts, spacing, name="Box"):
    """A closed box surface whose vertices are the integer points on the boundary of
    [0, counts] scaled by ``spacing``: at resolution ``max(counts)`` every vertex sits on
    a voxel corner (the grid is centred with one cell of margin on the longest axis)."""
    counts = np.asarray(counts)
    index = {}
    vertices = []
    for ijk in np.ndindex(*(counts + 1)):
        if any(c in (0, n) for c, n in zip(ijk, counts)):
            index[ijk] = len(vertices)
            vertices.append(np.array(ijk) * spacing)
    faces = []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for side in (0, counts[axis]):
            for a in range(counts[u]):
                for b in range(counts[v]):
                    quad = []
                    for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        ijk = [0, 0, 0]
                        ijk[axis], ijk[u], ijk[v] = side, a + du, b + dv
                        quad.append(index[tuple(ijk)])
                    faces.append(quad if side else quad[::-1])
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.array(vertices).tolist(), [], faces)
    mesh.validate()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    return obj


def two_bone_rig(obj, axis=0):
    """Two bones along ``axis`` of ``obj`` with hand-made linear weights (not automatic,
    so the test does not depend on bone heat)."""
    co = mesh_vertices(obj)
    lo, hi = co.min(axis=0), co.max(axis=0)
    mid = 0.5 * (lo + hi)
    start, joint, end = mid.copy(), mid.copy(), mid.copy()
    start[axis], joint[axis], end[axis] = lo[axis], mid[axis], hi[axis]
    data = bpy.data.armatures.new("Rig")
    rig = bpy.data.objects.new("Rig", data)
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    first = data.edit_bones.new("First")
    first.head, first.tail = start, joint
    second = data.edit_bones.new("Second")
    second.head, second.tail, second.parent, second.use_connect = joint, end, first, True
    bpy.ops.object.mode_set(mode="OBJECT")
    t = (co[:, axis] - lo[axis]) / (hi[axis] - lo[axis])
    for name, weights in (("First", 1 - t), ("Second", t)):
        group = obj.vertex_groups.new(name=name)
        for index, weight in enumerate(weights):
            group.add([index], float(weight), "REPLACE")
    modifier = obj.modifiers.new("Armature", "ARMATURE")
    modifier.object = rig
    bpy.context.view_layer.objects.active = obj
    return rig


def lattice_around(obj, margin=1.2, points=3, interpolation="KEY_BSPLINE"):
    co = mesh_vertices(obj)
    data = bpy.data.lattices.new("Cage")
    data.points_u = data.points_v = data.points_w = points
    data.interpolation_type_u = data.interpolation_type_v = interpolation
    data.interpolation_type_w = interpolation
    lattice = bpy.data.objects.new("Cage", data)
    bpy.context.scene.collection.objects.link(lattice)
    lattice.location = 0.5 * (co.min(axis=0) + co.max(axis=0))
    rest = np.array([p.co for p in data.points])
    lattice.scale = margin * np.ptp(co, axis=0).max() / np.ptp(rest, axis=0)
    modifier = obj.modifiers.new("Lattice", "LATTICE")
    modifier.object = lattice
    bpy.context.view_layer.update()
    return lattice


def mesh_vertices(obj):
    co = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def evaluated_vertices(obj):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    evaluated.to_mesh_clear()
    return co.reshape(-1, 3)
