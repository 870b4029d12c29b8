"""The two references of DESIGN section 9 for rays in the object's local deformed space.

- true reference: the rays cast against the Blender-evaluated deformed mesh;
- embedded reference: the walk through the deformed cells plus the exact rest-space ground
  truth of each segment: what the network is trained to reproduce.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..kernels.render import write_hits
from ..passes import Passes
from .groundtruth import cast_surface, segment_targets
from .traverse import traverse

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    from ..geometry.restmesh import RestMesh
    from ..geometry.walk_rules import Segments
    from ..kernels.cells import DeviceCells
    from ..kernels.surface import SurfaceCaster
    from .groundtruth import SurfaceHits


def true_reference(mesh: RestMesh, deformed_caster: SurfaceCaster,
                   origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"]
                   ) -> Passes:
    """Passes of rays (N, 3) against the deformed mesh: ``deformed_caster`` is a
    ``kernels.surface.SurfaceCaster`` holding the evaluated mesh's vertices and corner normals
    (the rest mesh's topology, e.g. ``PoseGeometry.mesh_caster``)."""
    hits = cast_surface(mesh, deformed_caster, origins, directions, np.inf)
    return Passes(hit=hits.hit, distance=hits.distance, normal=hits.normal,
                  albedo=hits.albedo, material=hits.material)


def embedded_reference(cells: DeviceCells, segments: Segments, targets: SurfaceHits,
                       rays: int) -> Passes:
    """Passes from segments and their rest ground truth: per ray the first segment with a
    hit, ``D = t0_k + s_k l_k`` (which equals the sum of gaps and lengths before it), the
    rest normal carried to deformed space by the inverse transpose Jacobian."""
    passes = Passes.empty(rays)
    first = segments.first_per_ray(targets.hit, rays)
    ray = np.flatnonzero(first >= 0)
    k = first[ray]
    rest_length = np.linalg.norm(segments.p1[k] - segments.p0[k], axis=1)
    fraction = np.where(rest_length > 0, targets.distance[k] / np.where(
        rest_length > 0, rest_length, 1.0), 0.0)
    set_hits(passes, ray, cells, segments, k, fraction, targets.normal[k],
             targets.albedo[k], targets.material[k])
    return passes


def set_hits(passes: Passes, ray: Int[np.ndarray, " H"], cells: DeviceCells, segments: Segments,
             k: Int[np.ndarray, " H"], fraction: Float[np.ndarray, " H"],
             rest_normal: Float[np.ndarray, "H 3"], albedo: Float[np.ndarray, "H 3"],
             material: Int[np.ndarray, " H"]) -> None:
    """Writes hits into ``passes`` for ``ray`` from their hit segment ``k`` and the hit
    ``fraction`` along it: deformed distance ``t0 + fraction * l`` and the rest normal
    carried to deformed space by ``J^-T`` of the cell's trilinear map at the rest hit, by
    the renderer's own kernel (``kernels/render.py``) on ``cells`` (a ``DeviceCells`` in
    the segments' pose)."""
    write_hits(cells, passes, ray, segments.cell[k], segments.t0[k], segments.t1[k],
               segments.p0[k], segments.p1[k], fraction, rest_normal, albedo, material)


def embedded_passes(cells: DeviceCells, mesh: RestMesh, rest_caster: SurfaceCaster,
                    origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"]
                    ) -> tuple[Passes, Segments, SurfaceHits]:
    """Walk + ground truth + embedded reference in one call: (Passes, Segments, targets)."""
    segments = traverse(cells, origins, directions)
    targets = segment_targets(mesh, rest_caster, segments)
    return embedded_reference(cells, segments, targets, len(origins)), segments, targets
