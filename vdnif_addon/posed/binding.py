"""Points (the voxel corners) bound to a surface's vertices at rest, moved with whatever
deforms that surface: the binding of corners that follow the evaluated surface
(``blender.deform.SurfaceCornerDeformer`` reads the surface from Blender; this module
touches no Blender data).

Each point takes the affine motion that best carries its nearby rest surface to the posed
one (moving least squares). Its anchors are the ``NEIGHBOURS`` nearest rest vertices and,
above each of them, the point one binding scale out along the vertex normal: the normals
give the fit its third dimension where the nearby vertices lie in a plane, so that a corner
off the surface turns with it. The weights are Shepard's with a radius at the next
neighbour's distance, ``((R - d) / (R d))^2``: a neighbour leaves the set with weight 0, so
the weights, the fit and the moved point all vary continuously with the rest position, and
a corner inside a thick body or an empty voxel follows the nearest surface's local motion
as smoothly as the surface moves. The fit reproduces any translation exactly, any rigid
motion of the neighbourhood up to its small regularisation (``REGULARISATION``; needed where
the anchors span less than three dimensions), and leaves a surface at rest exactly at rest.

The fit is linear in the posed anchors, so binding solves it once: a pose costs one
weighted sum of ``NEIGHBOURS`` posed vertices and normals per point, whatever the rest.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import VDNIFError

NEIGHBOURS = 8
"""Rest vertices each point is bound to: few keep the fit local, the way a bend or a
corrective shape moves the surface near the point (on small rigs at resolution 16, 8 has
from 0.7 to 0.45 times the distance error of 16 on a driven corrective key, a Corrective
Smooth and a lattice with an animated key); fewer make the motion steep between points
where the neighbours of a regular mesh are nearly tied (on a bent tube, points 1e-3 apart
move up to 5e-3 apart with 6 and 2e-2 with 4, against 1.4e-3 with 8)."""
REGULARISATION = 1e-6
"""Weight of the pull of the fitted linear map toward the identity, in binding-scale
squared: it only decides the directions the anchors do not span, far below their weighted
spread elsewhere (the Shepard weights can gather most of it on the nearest vertex, a spread
of a few hundredths of the scale squared), so a rigid motion is followed to well under 1e-3
of its angle times the point's distance from its anchors."""
_BLOCK_VALUES = 2**22
"""Distances a block of the nearest-vertex search holds (points x vertices, 32 MB of
float64; a few arrays of that size at once): a subdivided surface of a million vertices
then takes a handful of points a block, not gigabytes."""


@dataclass
class SurfaceBinding:
    """Points bound to a surface of ``vertex_count`` vertices: each moves to
    ``sum_k position[k] * position_weight[k] + normal[k] * normal_weight[k] + offset``
    over its ``index`` neighbours (see the module's docstring)."""

    index: np.ndarray              # (C, K) int64 neighbouring vertices
    position_weight: np.ndarray    # (C, K) float64
    normal_weight: np.ndarray      # (C, K) float64, binding scale included
    offset: np.ndarray             # (C, 3) float64 the regularisation's constant part
    vertex_count: int

    def moved(self, vertices, normals):
        """(C, 3) float64 the bound points for the posed surface: ``vertices`` (V, 3) and
        unit vertex ``normals`` (V, 3), on the rest surface's vertices."""
        if len(vertices) != self.vertex_count or len(normals) != self.vertex_count:
            raise VDNIFError(f"the surface has {len(vertices)} vertices in this pose and "
                             f"{self.vertex_count} at rest: its topology changes")
        vertices = np.asarray(vertices, np.float64)
        normals = np.asarray(normals, np.float64)
        return (np.einsum("ck,ckd->cd", self.position_weight, vertices[self.index])
                + np.einsum("ck,ckd->cd", self.normal_weight, normals[self.index])
                + self.offset)


def bind(points, vertices, normals, scale, neighbours=NEIGHBOURS):
    """The SurfaceBinding of ``points`` (C, 3) to the rest surface ``vertices`` (V, 3) with
    unit vertex ``normals`` (V, 3); ``scale``: the length of the normal anchors (the voxel
    size: the corners' distance from the surface)."""
    points = np.asarray(points, np.float64)
    vertices = np.asarray(vertices, np.float64)
    normals = np.asarray(normals, np.float64)
    if len(vertices) == 0:
        raise VDNIFError("the surface to bind to has no vertices")
    if not scale > 0:
        raise VDNIFError(f"the binding scale {scale} is not positive")
    k = min(neighbours, len(vertices) - 1) if len(vertices) > 1 else 1
    index, distance, radius = _nearest(points, vertices, k)
    weight = _shepard(distance, radius)                              # (C, K), rows sum to 1
    # anchors: each vertex and the point above it along its normal, half the weight each
    anchors = np.stack([vertices[index], vertices[index] + scale * normals[index]], 2)
    omega = np.repeat(weight[:, :, None] / 2, 2, axis=2)             # (C, K, 2)
    mean = np.einsum("cka,ckad->cd", omega, anchors)
    centred = anchors - mean[:, None, None]
    spread = np.einsum("cka,ckad,ckae->cde", omega, centred, centred)
    lam = REGULARISATION * scale * scale
    inverse = np.linalg.inv(spread + lam * np.eye(3))
    reach = inverse @ (points - mean)[:, :, None]                    # (C, 3, 1): M (x - mean)
    beta = omega * (1 + np.einsum("ckad,cd->cka", centred, reach[:, :, 0]))
    return SurfaceBinding(index=index, position_weight=beta.sum(2),
                          normal_weight=scale * beta[:, :, 1],
                          offset=lam * reach[:, :, 0], vertex_count=len(vertices))


def vertex_normals(vertices, triangles):
    """(V, 3) unit area-weighted vertex normals of a triangle mesh (a vertex of no
    triangle gets +Z): for surfaces read without Blender's own."""
    vertices = np.asarray(vertices, np.float64)
    corners = vertices[triangles]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for column in range(3):
        np.add.at(normals, triangles[:, column], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(length > 0, normals / np.where(length > 0, length, 1), [0.0, 0.0, 1.0])


def _nearest(points, vertices, k):
    """(index (C, k), distance (C, k), radius (C,)): each point's ``k`` nearest vertices
    and the distance of the next one (the Shepard radius; beyond the last vertex, twice the
    farthest neighbour's)."""
    take = min(k + 1, len(vertices))
    square = (vertices * vertices).sum(1)
    index = np.empty((len(points), k), np.int64)
    distance = np.empty((len(points), k))
    radius = np.empty(len(points))
    chunk = max(1, _BLOCK_VALUES // len(vertices))
    for start in range(0, len(points), chunk):
        block = points[start:start + chunk]
        d2 = np.maximum((block * block).sum(1)[:, None] + square[None] - 2 * block @ vertices.T,
                        0.0)
        near = np.argpartition(d2, take - 1, axis=1)[:, :take] if take < len(vertices) \
            else np.broadcast_to(np.arange(len(vertices)), (len(block), len(vertices)))
        near_d2 = np.take_along_axis(d2, near, 1)
        order = np.argsort(near_d2, axis=1)
        near, near_d2 = np.take_along_axis(near, order, 1), np.take_along_axis(near_d2, order, 1)
        # the exact distances (the expansion above loses digits next to a vertex)
        exact = np.linalg.norm(block[:, None] - vertices[near], axis=2)
        index[start:start + len(block)] = near[:, :k]
        distance[start:start + len(block)] = exact[:, :k]
        radius[start:start + len(block)] = (exact[:, k] if take > k
                                            else 2 * exact[:, k - 1] + 1e-12)
    return index, distance, radius


def _shepard(distance, radius):
    """(C, K) normalised weights ((R - d)_+ / (R d))^2, a point on a vertex bound to it."""
    radius = np.maximum(radius, distance.max(1) * (1 + 1e-12))[:, None]
    tiny = 1e-9 * radius
    weight = (np.maximum(radius - distance, 0.0) / (radius * np.maximum(distance, tiny))) ** 2
    total = weight.sum(1, keepdims=True)
    return np.where(total > 0, weight / np.where(total > 0, total, 1), 1.0 / distance.shape[1])
