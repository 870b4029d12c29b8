"""The numpy ground truth that ``kernels.surface`` replaced, kept as its test oracle.

Any caster with ``cast(origins, directions, max_distance) -> (index, t)`` (Blender's BVHTree
through ``blender.bvh.BVHCaster``, ``traverse.BruteForceCaster``) finds the hit; the hit
point's barycentric weights and shading normal are then computed in numpy, exactly as the
pipeline did before the kernel: the point ``origin + t direction`` with the caster's ``t``
(float32 for a BVH), projected onto the triangle's plane.
"""

import numpy as np

from vdnif_addon.geometry.attributes import (
    FALLBACK_NORMAL,
    has_area,
    interpolate,
    normalize,
    surface_albedo,
)
from vdnif_addon.tracing.groundtruth import BOUNDARY_MARGIN, SurfaceHits


def barycentric(points, corners) -> np.ndarray:
    """(N, 3) float64 weights of each point (N, 3) w.r.t. its triangle corners (N, 3, 3).

    The point is projected onto the triangle's plane (weights are not clamped, so a point
    outside the triangle gets negative weights). A degenerate triangle (collinear corners)
    has no plane: the point is projected onto its longest edge, clamped to that segment, which
    for collinear corners is the whole triangle; if all corners coincide the weights are 1/3
    each. Weights always sum to 1 and are finite.
    """
    points = np.asarray(points, dtype=np.float64)
    corners = np.asarray(corners, dtype=np.float64)
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    d = points - corners[:, 0]
    d11, d12, d22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    denom = d11 * d22 - d12 * d12
    planar = has_area(corners)
    safe = np.where(planar, denom, 1.0)
    w1 = (d22 * _dot(d, e1) - d12 * _dot(d, e2)) / safe
    w2 = (d11 * _dot(d, e2) - d12 * _dot(d, e1)) / safe
    weights = np.stack([1.0 - w1 - w2, w1, w2], axis=1)
    return np.where(planar[:, None], weights, _segment_weights(points, corners))


def _segment_weights(points, corners) -> np.ndarray:
    """(N, 3) weights of the nearest point on each triangle's longest edge (degenerate case)."""
    start = np.array([0, 1, 2])
    end = np.array([1, 2, 0])
    edges = corners[:, end] - corners[:, start]                     # (N, 3 edges, 3)
    longest = np.argmax(_dot(edges, edges), axis=1)                 # (N,)
    rows = np.arange(len(points))
    edge = edges[rows, longest]
    length2 = _dot(edge, edge)
    t = np.clip(_dot(points - corners[rows, start[longest]], edge)
                / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    weights = np.zeros((len(points), 3))
    weights[rows, start[longest]] = 1.0 - t
    weights[rows, end[longest]] = t
    return np.where(length2[:, None] > 0, weights, 1.0 / 3.0)


def shading_normals(vertices, triangles, corner_normals, triangle, weights) -> np.ndarray:
    """(N, 3) unit normals at triangle (N,) with weights (N, 3): interpolated corner normals
    (T, 3, 3) renormalized, else the geometric face normal, else +Z."""
    corners = np.asarray(vertices, dtype=np.float64)[triangles[triangle]]
    face_normal = normalize(np.cross(corners[:, 1] - corners[:, 0],
                                     corners[:, 2] - corners[:, 0]), FALLBACK_NORMAL)
    return normalize(interpolate(np.asarray(corner_normals, dtype=np.float64)[triangle],
                                 weights), face_normal)


def cast_surface(mesh, caster, origins, directions, max_distance, vertices=None,
                 normals=None):
    """SurfaceHits of rays against ``mesh`` (via ``caster`` built on the same triangles);
    ``vertices``/``normals`` give a deformed pose of the mesh."""
    vertices = mesh.vertices if vertices is None else vertices
    normals = mesh.corner_normals if normals is None else normals
    triangle, distance = caster.cast(origins, directions, max_distance)
    hit = triangle >= 0
    count = len(origins)
    hits = SurfaceHits(hit=hit, distance=np.where(hit, distance, 0.0), triangle=triangle,
                       weights=np.zeros((count, 3)), normal=np.zeros((count, 3)),
                       albedo=np.zeros((count, 3), np.float32),
                       material=np.zeros(count, np.int32))
    if hit.any():
        points = origins[hit] + distance[hit, None] * directions[hit]
        corners = np.asarray(vertices, np.float64)[mesh.triangles[triangle[hit]]]
        hits.weights[hit] = barycentric(points, corners)
        hits.normal[hit] = shading_normals(vertices, mesh.triangles, normals, triangle[hit],
                                           hits.weights[hit])
        hits.albedo[hit], hits.material[hit] = surface_albedo(mesh, triangle[hit],
                                                              hits.weights[hit])
    return hits


def segment_targets(mesh, rest_caster, segments):
    """SurfaceHits of each rest segment, cast from BOUNDARY_MARGIN of the object size before
    ``p0`` to as far after ``p1``; ``distance`` from ``p0``, clamped to the segment."""
    offset = segments.p1 - segments.p0
    rest_length = np.linalg.norm(offset, axis=1)
    usable = rest_length > 0
    directions = offset / np.where(usable, rest_length, 1.0)[:, None]
    margin = BOUNDARY_MARGIN * mesh.size
    hits = cast_surface(mesh, rest_caster, segments.p0 - margin * directions, directions,
                        np.where(usable, rest_length + 2 * margin, -1.0))
    hits.distance = np.where(hits.hit, np.clip(hits.distance - margin, 0.0, rest_length), 0.0)
    return hits


def _dot(a, b) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)
