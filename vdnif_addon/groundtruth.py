"""Ground truth for rest-space segments (DESIGN section 6): cast ``p0 -> p1`` against the rest
mesh and read the surface attributes at the hit."""

from dataclasses import dataclass

import numpy as np

from .attributes import barycentric, surface_attributes

BOUNDARY_MARGIN = 1e-6


@dataclass
class SurfaceHits:
    """What a set of rays or segments hits: attributes are zero where ``hit`` is False."""

    hit: np.ndarray          # (N,) bool
    distance: np.ndarray     # (N,) float64 along the ray or segment (0 on a miss)
    triangle: np.ndarray     # (N,) int64, -1 on a miss
    weights: np.ndarray      # (N, 3) float64 barycentric weights of the hit
    normal: np.ndarray       # (N, 3) float64 unit shading normal
    albedo: np.ndarray       # (N, 3) float32
    material: np.ndarray     # (N,) int32


def cast_surface(mesh, caster, origins, directions, max_distance, vertices=None, normals=None):
    """First hits of rays against ``mesh`` (via ``caster`` built on the same triangles) with
    their shading attributes. ``vertices``/``normals`` give a deformed pose of the mesh."""
    vertices = mesh.vertices if vertices is None else vertices
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
        attributes = surface_attributes(mesh, triangle[hit], hits.weights[hit],
                                        normals=normals, vertices=vertices)
        hits.normal[hit] = attributes["normal"]
        hits.albedo[hit] = attributes["albedo"]
        hits.material[hit] = attributes["material"]
    return hits


def segment_targets(mesh, rest_caster, segments):
    """SurfaceHits of each rest segment; ``distance`` is the rest-space local distance d
    from ``p0``. The hit fraction along the segment is ``distance / rest_length``.

    Each cast starts a hair before ``p0`` and ends a hair after ``p1`` (BOUNDARY_MARGIN of
    the object size): a surface lying exactly on a cell face (a flat cap on a grid plane)
    is otherwise missed by both segments that share the face, since a float32 BVH cast
    starting or ending on a surface may not report it. The earlier segment keeps it.
    """
    offset = segments.p1 - segments.p0
    rest_length = np.linalg.norm(offset, axis=1)
    usable = rest_length > 0
    directions = offset / np.where(usable, rest_length, 1.0)[:, None]
    margin = BOUNDARY_MARGIN * mesh.size
    hits = cast_surface(mesh, rest_caster, segments.p0 - margin * directions, directions,
                        np.where(usable, rest_length + 2 * margin, -1.0))
    hits.distance = np.where(hits.hit, np.clip(hits.distance - margin, 0.0, rest_length), 0.0)
    return hits
