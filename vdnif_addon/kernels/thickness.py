"""How thick a mesh is where it is thinnest: the local thickness of every triangle, measured
by casting a ray from its centroid inward along its normal to where it leaves the solid,
and the thickness that a given share of the surface area is thinner than.

A voxel grid resolves a part only where it spans a few voxels: the suggested resolution
(``blender/resolution.py``) is raised until the thin parts do.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .cast import MeshCaster

if TYPE_CHECKING:
    from jaxtyping import Float, Int

# The ray starts this share of the mesh size inside the surface, so that it never hits the
# triangle it leaves (float32 casts) yet measures walls far thinner than any voxel.
START_INSIDE = 1e-6


def triangle_thickness(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
                       caster: MeshCaster | None = None
                       ) -> tuple[Float[np.ndarray, " T"], Float[np.ndarray, " T"]]:
    """(thickness (T,), area (T,)): per triangle, the distance from its centroid along its
    inward (winding) normal to the first surface the ray meets, where that surface faces
    away from the ray (the ray leaves the solid there); inf where the ray meets nothing or
    first enters another part through its outside (an open sheet, or normals pointing in),
    and for degenerate triangles (area 0). ``caster``: a MeshCaster of the same mesh."""
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    corners = vertices[triangles]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    area = 0.5 * double_area
    thickness = np.full(len(triangles), np.inf)
    valid = double_area > 0
    if not valid.any():
        return thickness, area
    normals = cross[valid] / double_area[valid, None]
    extent = np.ptp(vertices, axis=0)
    start = START_INSIDE * float(extent.max())
    inward = -normals
    origins = corners[valid].mean(axis=1) + start * inward
    caster = caster or MeshCaster(vertices, triangles)
    index, distance = caster.cast(origins, inward, 2.0 * float(np.linalg.norm(extent)))
    hit = index >= 0
    leaves = np.zeros(len(index), bool)
    hit_normals = cross[index[hit]]
    leaves[hit] = np.einsum("ij,ij->i", hit_normals, inward[hit]) > 0
    thickness[np.flatnonzero(valid)[leaves]] = distance[leaves] + start
    return thickness, area


def thin_thickness(thickness: Float[np.ndarray, " T"], area: Float[np.ndarray, " T"],
                   share: float) -> float:
    """The thickness that ``share`` of the surface area (of the triangles with a measured
    thickness and of those without, which count as thick) is thinner than or as thin as;
    inf when less than ``share`` has a measured thickness."""
    total = float(area.sum())
    if total <= 0:
        return float("inf")
    order = np.argsort(thickness, kind="stable")
    covered = np.cumsum(area[order]) / total
    first = int(np.searchsorted(covered, share))
    return float(thickness[order[min(first, len(order) - 1)]])
