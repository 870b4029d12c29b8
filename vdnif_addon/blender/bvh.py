"""Ray casts against triangles with Blender's BVHTree (mathutils): the entry caster over the
boundary faces of deformed cells, the classical baseline of ``side-by-side`` and the
independent check of the Warp casts in tests (the ground truth and the true reference cast
with ``kernels.surface``). BVHTree has no batch API, so this is a Python loop over rays."""

import bpy  # noqa: F401  (mathutils must be imported after bpy)
import numpy as np
from mathutils.bvhtree import BVHTree


class BVHCaster:
    """First hits of rays against a triangle mesh; same interface as
    ``BruteForceCaster`` (tests/oracles/geometry.py)."""

    def __init__(self, vertices, triangles):
        """``vertices`` (V, 3), ``triangles`` (T, 3) vertex indices; hit indices are rows
        of ``triangles``."""
        self.tree = BVHTree.FromPolygons(np.asarray(vertices, np.float64).tolist(),
                                         np.asarray(triangles).tolist(), all_triangles=True)

    def cast(self, origins, directions, max_distance):
        """(index (N,) int64, -1 on a miss; t (N,) inf on a miss)."""
        limits = np.minimum(np.asarray(max_distance, np.float64), 1e30).tolist()
        results = list(map(self.tree.ray_cast, np.asarray(origins).tolist(),
                           np.asarray(directions).tolist(), limits))
        index = np.fromiter((-1 if r[2] is None else r[2] for r in results), np.int64,
                            len(results))
        t = np.fromiter((np.inf if r[3] is None else r[3] for r in results), np.float64,
                        len(results))
        return index, t
