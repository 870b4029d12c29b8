"""First hits of rays against a triangle mesh held as a Warp BVH (``wp.Mesh``).

The caster behind every ray query of the pipeline: the entry faces of the deformed cells, the
rest mesh for segment ground truth, the deformed mesh for the true reference. A mesh whose
vertices move but keep their triangles is ``refit`` (bounds updated in place) rather than
rebuilt. Same interface as ``BruteForceCaster`` (tests/oracles/geometry.py), the reference
it is tested against.
Geometry is float32 in the BVH (as in Blender's BVHTree); callers that need more refine the
hit on its triangle in float64.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from . import launches, runtime

WARP_MODULE = runtime.warp_module(__name__)

if TYPE_CHECKING:
    from jaxtyping import Float, Int


@wp.kernel(module=WARP_MODULE)
def _first_hits(
    mesh: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_distance: wp.array(dtype=wp.float32),
    face: wp.array(dtype=wp.int32),
    distance: wp.array(dtype=wp.float32),
):
    i = wp.tid()
    face[i] = -1
    distance[i] = wp.inf    # written on a miss too: the host reads every entry
    limit = max_distance[i]
    if limit < 0.0:
        return
    query = wp.mesh_query_ray(mesh, origins[i], directions[i], limit)
    if query.result:
        face[i] = query.face
        distance[i] = query.t


class MeshCaster:
    """A triangle mesh as a Warp BVH on ``device``: ``vertices`` (V, 3), ``triangles`` (T, 3)
    vertex indices; hit indices are rows of ``triangles``."""

    def __init__(self, vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
                 device: str = "cpu") -> None:
        wp_ = runtime.init()
        runtime.load(WARP_MODULE, device)
        self.device = device
        triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
        self.triangle_count = len(triangles)
        self.points = wp_.array(np.asarray(vertices, np.float32).reshape(-1, 3), dtype=wp_.vec3,
                                device=device)
        self.mesh = None
        if self.triangle_count:
            self.indices = wp_.array(triangles.ravel(), dtype=wp_.int32, device=device)
            self.mesh = wp_.Mesh(points=self.points, indices=self.indices,
                                 bvh_constructor=runtime.BVH_CONSTRUCTOR)

    def refit(self, vertices: Float[np.ndarray, "V 3"]) -> None:
        """Moves the vertices (same count and triangles) and updates the BVH's bounds."""
        self.points.assign(np.asarray(vertices, np.float32).reshape(-1, 3))
        if self.mesh is not None:
            self.mesh.refit()

    def cast(self, origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"],
             max_distance: float | Float[np.ndarray, " N"], threads: int = 1
             ) -> tuple[Int[np.ndarray, " N"], Float[np.ndarray, " N"]]:
        """(index (N,) int64, -1 on a miss; t (N,) float64, inf on a miss): the first hit
        with 0 <= t <= max_distance (a negative limit casts nothing). On the CPU the rays
        are split over ``threads`` launches at once (``kernels.launches``)."""
        count = len(origins)
        if self.mesh is None or count == 0:
            return np.full(count, -1, np.int64), np.full(count, np.inf)
        limits = np.minimum(np.broadcast_to(np.asarray(max_distance, np.float64), (count,)),
                            np.finfo(np.float32).max)
        arrays = [wp.array(np.asarray(x, np.float32), dtype=t, device=self.device)
                  for x, t in ((origins, wp.vec3), (directions, wp.vec3), (limits, wp.float32))]
        face = wp.empty(count, dtype=wp.int32, device=self.device)
        distance = wp.empty(count, dtype=wp.float32, device=self.device)
        workers = launches.parts(self.device, count, threads)
        launches.run(_first_hits, self.device, None, workers,
                     [(stop - first, [self.mesh.id, *(x[first:stop]
                                                      for x in (*arrays, face, distance))])
                      for first, stop in launches.bounds(count, workers)])
        return face.numpy().astype(np.int64), distance.numpy().astype(np.float64)
