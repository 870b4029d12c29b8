"""A mesh's separate pieces, the small ones that ride on its largest piece (an eye in its
socket), and whether an armature moves a riding piece otherwise than the surface it touches.

One voxel gives every point inside it one motion (DESIGN section 4), so a piece that moves
apart from the surface it touches within a voxel cannot be followed: Blender's automatic
weights weight each piece by itself, and an artist may give an eye a bone of its own. The
procedural armature weights a riding piece as the surface it touches
(``scenes.follow_riders``); of any other armature rig, ``sliding`` says which pieces move
otherwise, and the corners' choice says so where it reports (``follow_choice``).
"""

import bpy  # noqa: F401  (mathutils must be imported after bpy)
import numpy as np
from mathutils.bvhtree import BVHTree
from mathutils.kdtree import KDTree

from ..geometry.framing import components

RIDER_REACH = 0.01
"""A separate piece with a vertex within this share of the largest piece's longest side of
that piece's surface touches it: an eye sits in its socket, closer than any voxel."""
RIDER_SIZE = 0.25
"""A touching piece whose bounding-box diagonal is at most this share of the largest
piece's rides on it (eyes, teeth, buttons are small beside the body they sit on); a larger
one, a limb modelled apart, keeps the weights of its own."""
SLIDE_DIFFERENCE = 0.1
"""A riding piece slides when, at any of its vertices, the summed absolute difference of
the normalized bone weights from its nearest largest-piece vertex's exceeds this (0 alike,
2 on other bones): a tenth of a bone's turn, far above rounding, where a piece weighted by
itself differs by several tenths (docs/results.md, "The shaded image")."""


def riders(obj):
    """(vertices, sources): the vertices of ``obj``'s pieces that ride on its largest piece
    (``RIDER_REACH``, ``RIDER_SIZE``), and each one's nearest vertex of the largest piece.

    A piece is a connected set of faces (``geometry.framing.components``), the largest the
    one with the most vertices; nothing rides on a mesh of one piece."""
    vertices, sources, _, _ = _riders(obj)
    return vertices, sources


def _riders(obj):
    """``riders``, with every vertex's coordinates (V, 3) and piece label (V,)."""
    triangles = _triangles(obj)
    flat = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", flat)
    vertices = flat.reshape(-1, 3)
    _, piece = np.unique(components(len(vertices), triangles), return_inverse=True)
    none = np.zeros(0, np.int64)
    counts = np.bincount(piece)
    if len(counts) < 2:
        return none, none, vertices, piece
    pieces = np.split(np.argsort(piece, kind="stable"), np.cumsum(counts)[:-1])
    largest = pieces[counts.argmax()]
    tree = KDTree(len(largest))
    for index, co in zip(largest, vertices[largest]):
        tree.insert(co, int(index))
    tree.balance()
    surface = BVHTree.FromPolygons(vertices.tolist(),
                                   triangles[piece[triangles[:, 0]] == counts.argmax()].tolist())
    diagonal = lambda co: float(np.linalg.norm(np.ptp(co, axis=0)))  # noqa: E731
    reach = RIDER_REACH * float(np.ptp(vertices[largest], axis=0).max())
    size = RIDER_SIZE * diagonal(vertices[largest])
    chosen, sources = [none], [none]
    for label, members in enumerate(pieces):
        if label == counts.argmax() or diagonal(vertices[members]) > size:
            continue
        # find_nearest answers (None, ...) beyond ``reach``; a vertex on the surface, 0.0
        if any(surface.find_nearest(co, reach)[3] is not None for co in vertices[members]):
            chosen.append(members)
            sources.append(np.array([tree.find(co)[1] for co in vertices[members]], np.int64))
    return np.concatenate(chosen), np.concatenate(sources), vertices, piece


def group_weights(obj, names, indices=None):
    """(len(indices), len(names)) the weights of the vertices ``indices`` of ``obj`` (default
    every vertex) in its vertex groups ``names``, in that order (0 where a vertex is not in
    a group, or the group does not exist)."""
    columns = {obj.vertex_groups[name].index: k for k, name in enumerate(names)
               if name in obj.vertex_groups}
    if indices is None:
        indices = range(len(obj.data.vertices))
    weights = np.zeros((len(indices), len(names)))
    for row, index in enumerate(indices):
        for group in obj.data.vertices[int(index)].groups:
            if group.group in columns:
                weights[row, columns[group.group]] = group.weight
    return weights


def _deform_groups(obj):
    """The names of ``obj``'s vertex groups that its enabled Armature modifiers deform it by:
    those of the armatures' deforming bones."""
    names = []
    for modifier in obj.modifiers:
        if (modifier.type == "ARMATURE" and modifier.show_viewport and modifier.use_vertex_groups
                and modifier.object is not None and modifier.object.type == "ARMATURE"):
            names += [bone.name for bone in modifier.object.data.bones
                      if bone.use_deform and bone.name not in names]
    return [name for name in names if name in obj.vertex_groups]


def armature_weights(obj, indices=None):
    """(len(indices), bones) the normalized weights of the vertices ``indices`` of ``obj``
    (default every vertex) in the vertex groups named after the deforming bones of its
    enabled Armature modifiers (0 where a vertex has none); None when no armature deforms
    it by vertex groups."""
    names = _deform_groups(obj)
    if not names:
        return None
    return normalized(group_weights(obj, names, indices))


def normalized(weights):
    """Bone weights (V, bones) with each row over its sum, as an armature blends them (a
    row of zeros stays zero)."""
    return weights / np.maximum(weights.sum(1, keepdims=True), 1e-30)


def sliding(obj):
    """The riding pieces of ``obj`` that its armature moves otherwise than the surface they
    touch (``SLIDE_DIFFERENCE``): a tuple of (vertices, centre (x, y, z) in object space,
    largest weight difference) per piece; empty without an armature or a riding piece.
    Only the riding vertices and their sources' weights are read (a Python loop each)."""
    if not _deform_groups(obj):
        return ()
    vertices, sources, co, piece = _riders(obj)
    if not len(vertices):
        return ()
    difference = np.abs(armature_weights(obj, vertices)
                        - armature_weights(obj, sources)).sum(1)
    found = []
    for label in np.unique(piece[vertices]):
        inside = piece[vertices] == label
        largest = float(difference[inside].max())
        if largest > SLIDE_DIFFERENCE:
            centre = co[vertices[inside]].mean(0)
            found.append((int(inside.sum()), tuple(float(x) for x in centre), largest))
    return tuple(found)


def describe_sliding(pieces):
    """One clause for the corners' report: how many pieces slide, where, and what follows."""
    where = ", ".join(f"({', '.join(f'{x:.2g}' for x in centre)})" for _, centre, _ in pieces)
    worst = max(difference for _, _, difference in pieces)
    return (f"{len(pieces)} separate piece{'s' if len(pieces) > 1 else ''} at {where} "
            f"move{'' if len(pieces) > 1 else 's'} otherwise than the surface "
            f"{'they touch' if len(pieces) > 1 else 'it touches'} (bone weights differ by up to "
            f"{worst:.2g}); the voxels give both one motion, so expect errors around "
            f"{'them' if len(pieces) > 1 else 'it'} (weight each as that surface)")


def _triangles(obj):
    """(T, 3) the vertex indices of ``obj``'s triangles."""
    obj.data.calc_loop_triangles()
    triangles = np.empty(len(obj.data.loop_triangles) * 3, np.int64)
    obj.data.loop_triangles.foreach_get("vertices", triangles)
    return triangles.reshape(-1, 3)
