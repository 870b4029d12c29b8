"""Bone and lattice helpers that the pose sampler (``poses``), the stress poses (``extremes``)
and the demo scenes (``scenes``) share: which bones move a mesh, which lattice points reach
it, offsetting lattice points, and the bend-and-twist of a unit lattice."""

import bpy
import numpy as np

from ..errors import VDNIFError


def influencing_bones(obj, modifier):
    """Bones of the armature that move ``obj``: weighted deform bones and their ancestors."""
    armature = modifier.object
    bones = armature.data.bones
    weighted = set()
    if modifier.use_bone_envelopes:
        weighted = {b.name for b in bones if b.use_deform}
    if modifier.use_vertex_groups:
        weighted |= {b.name for b in bones if b.use_deform and b.name in _weighted_groups(obj)}
    moving = set()
    for name in weighted:
        bone = bones[name]
        while bone is not None:
            moving.add(bone.name)
            bone = bone.parent
    return sorted(moving, key=lambda name: bones.find(name))


def moving_lattice_points(obj, modifier):
    """Indices of lattice points whose support reaches the mesh (the others move nothing)."""
    lattice = modifier.object
    rest, cell = lattice_cells(lattice.data)
    to_lattice = np.array(lattice.matrix_world.inverted() @ obj.matrix_world)
    vertices = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", vertices)
    vertices = vertices.reshape(-1, 3) @ to_lattice[:3, :3].T + to_lattice[:3, 3]
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    data = lattice.data
    interpolation = (data.interpolation_type_u, data.interpolation_type_v,
                     data.interpolation_type_w)
    reach = cell * np.array([1.0 if kind == "KEY_LINEAR" else 2.0 for kind in interpolation])
    inside = np.all((rest + reach > lo) & (rest - reach < hi), axis=1)
    return np.flatnonzero(inside).tolist()


def lattice_cells(data):
    """(P, 3) rest positions of the lattice points in lattice space and (3,) cell size."""
    rest = np.array([p.co for p in data.points])
    counts = np.array([data.points_u, data.points_v, data.points_w])
    return rest, np.ptp(rest, axis=0) / np.maximum(counts - 1, 1)


def _weighted_groups(obj):
    """Names of the vertex groups that hold a non-zero weight somewhere in the mesh."""
    used = set()
    for vertex in obj.data.vertices:
        used.update(g.group for g in vertex.groups if g.weight > 0)
    return {obj.vertex_groups[i].name for i in used}


def offset_lattice(spec):
    """Offsets lattice points; with shape keys every key block moves, so the blend of the
    keys moves by exactly the offset."""
    lattice = bpy.data.objects.get(spec["object"])
    if lattice is None or lattice.type != "LATTICE":
        raise VDNIFError(f"pose names lattice '{spec['object']}', which is not in the scene")
    data = lattice.data
    keys = data.shape_keys.key_blocks if data.shape_keys else None
    targets = [(block.data, "co") for block in keys] if keys else [(data.points, "co_deform")]
    saved = []
    for points, attribute in targets:
        co = np.empty(len(points) * 3, np.float32)
        points.foreach_get(attribute, co)
        saved.append((points, attribute, co))
        moved = co.reshape(-1, 3).copy()
        for index, offset in spec["offsets"].items():
            moved[int(index)] += offset
        points.foreach_set(attribute, moved.ravel())
    data.update_tag()

    def undo():
        for points, attribute, co in saved:
            points.foreach_set(attribute, co)
        data.update_tag()

    return undo


def bend_twist(points, axis, bend, twist):
    """Lattice-space (unit cube) points twisted about ``axis`` and bent across it."""
    u, v = (axis + 1) % 3, (axis + 2) % 3
    along = points[:, axis] + 0.5
    out = points.copy()
    angle = twist * along
    out[:, u] = np.cos(angle) * points[:, u] - np.sin(angle) * points[:, v]
    out[:, v] = np.sin(angle) * points[:, u] + np.cos(angle) * points[:, v]
    out[:, u] += 0.5 * bend * along ** 2
    return out
