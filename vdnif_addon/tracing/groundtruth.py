"""Ground truth for rest-space segments (DESIGN section 6): cast ``p0 -> p1`` against the rest
mesh and read the surface attributes at the hit.

The casts, barycentric weights and shading normals run as one kernel over all segments (or
rays) on a ``kernels.surface.SurfaceCaster``; albedo and material are read here, over hits
only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.attributes import surface_albedo
from ..kernels.surface import SurfaceCaster

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

    from ..geometry.restmesh import RestMesh
    from ..geometry.voxels import VoxelGrid
    from ..geometry.walk_rules import Segments

BOUNDARY_MARGIN = 1e-6


@dataclass
class SurfaceHits:
    """What a set of rays or segments hits: attributes are zero where ``hit`` is False."""

    hit: Bool[np.ndarray, " N"]
    distance: Float[np.ndarray, " N"]       # float64 along the ray or segment (0 on a miss)
    triangle: Int[np.ndarray, " N"]         # int64, -1 on a miss
    weights: Float[np.ndarray, "N 3"]      # float64 barycentric weights of the hit
    normal: Float[np.ndarray, "N 3"]       # float64 unit shading normal
    albedo: Float[np.ndarray, "N 3"]       # float32
    material: Int[np.ndarray, " N"]         # int32


def rest_surface(mesh: RestMesh, grid: VoxelGrid | None = None, device: str = "cpu"
                 ) -> SurfaceCaster:
    """The rest mesh (a RestMesh) as a SurfaceCaster, built once per capture. Given the
    VoxelGrid, each cell keeps the triangles its segments can hit (their casts reach
    BOUNDARY_MARGIN of the object size beyond the cell: the lists take twice that, so float32
    bounds never drop one); without it segments are cast against the whole mesh."""
    boxes, reach = None, 0.0
    if grid is not None:
        boxes = grid.cell_bounds(np.arange(len(grid.cells)))
        reach = 2 * BOUNDARY_MARGIN * mesh.size
    return SurfaceCaster(mesh.vertices, mesh.triangles, mesh.corner_normals, device,
                         cell_boxes=boxes, cell_margin=reach)


def cast_surface(mesh: RestMesh, caster: SurfaceCaster, origins: Float[np.ndarray, "N 3"],
                 directions: Float[np.ndarray, "N 3"],
                 max_distance: float | Float[np.ndarray, " N"]) -> SurfaceHits:
    """First hits of rays (N, 3) within ``max_distance`` against ``caster`` (a SurfaceCaster
    of ``mesh``'s triangles, in whichever pose it holds) with their shading attributes."""
    return _surface_hits(mesh, *caster.cast_rays(origins, directions, max_distance))


def segment_targets(mesh: RestMesh, rest_caster: SurfaceCaster, segments: Segments
                    ) -> SurfaceHits:
    """SurfaceHits of each rest segment on ``rest_caster`` (``rest_surface(mesh, grid)``,
    the grid whose cells ``segments.cell`` indexes);
    ``distance`` is the rest-space local distance d from ``p0``. The hit fraction along the
    segment is ``distance / rest_length``.

    Each cast starts a hair before ``p0`` and ends a hair after ``p1`` (BOUNDARY_MARGIN of
    the object size): a surface lying exactly on a cell face (a flat cap on a grid plane)
    is otherwise missed by both segments that share the face, since a float32 BVH cast
    starting or ending on a surface may not report it. The earlier segment keeps it.
    """
    return _surface_hits(mesh, *rest_caster.cast_segments(
        segments.p0, segments.p1, segments.cell, BOUNDARY_MARGIN * mesh.size))


def _surface_hits(mesh: RestMesh, triangle: Int[np.ndarray, " N"],
                  distance: Float[np.ndarray, " N"], weights: Float[np.ndarray, "N 3"],
                  normal: Float[np.ndarray, "N 3"]) -> SurfaceHits:
    """SurfaceHits of casts that found ``triangle`` (-1 on a miss), with albedo and material
    read over the hits."""
    hit = triangle >= 0
    count = len(triangle)
    albedo = np.zeros((count, 3), np.float32)
    material = np.zeros(count, np.int32)
    if hit.any():
        albedo[hit], material[hit] = surface_albedo(mesh, triangle[hit], weights[hit])
    return SurfaceHits(hit=hit, distance=distance, triangle=triangle, weights=weights,
                       normal=normal, albedo=albedo, material=material)
