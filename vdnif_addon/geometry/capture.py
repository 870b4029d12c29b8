"""What scene capture produces: rest mesh, voxel grid and per-pose deformed corners."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .restmesh import RestMesh
from .voxels import VoxelGrid, inverted_cells

if TYPE_CHECKING:
    from jaxtyping import Float, Int

ARMATURE_COPY = "armature copy"
"""How the corners follow the mesh: copies of its armature and lattice modifiers
(``blender.deform``), exact where nothing else deforms it."""
EVALUATED_SURFACE = "evaluated surface"
"""How the corners follow the mesh: bound to the surface Blender evaluates at rest and moved
with it (``posed.binding``), for any other deformation that keeps the topology; where a
subdivision ends the stack, to its cage (the surface before it)."""
SUBDIVIDED_SURFACE = "subdivided surface"
"""As ``EVALUATED_SURFACE``, but bound to the surface after the subdivision that ends the
stack: closer where the cage is coarse, dearer in every pose."""
CORNERS_FOLLOW = (ARMATURE_COPY, EVALUATED_SURFACE, SUBDIVIDED_SURFACE)
SURFACE_BOUND = (EVALUATED_SURFACE, SUBDIVIDED_SURFACE)
"""The ways that bind the corners to the evaluated surface."""


@dataclass
class Capture:
    """A captured deforming object (DESIGN sections 2-4, 7).

    ``corners[p]`` holds the deformed position of every used voxel corner of
    ``grid.corners`` for ``poses[p]``, in the object's local deformed space.
    """

    mesh: RestMesh
    grid: VoxelGrid
    mode: str                          # "armature", "lattice", "armature+lattice", "static" or
                                       # "animated" (frames move it, no rig)
    poses: list[dict[str, Any]]        # JSON-ready pose descriptions
    corners: Float[np.ndarray, "P C 3"]    # float64
    timings: dict[str, float] = field(default_factory=dict)
    corners_follow: str = ARMATURE_COPY    # one of CORNERS_FOLLOW

    @property
    def inverted_cells(self) -> Int[np.ndarray, " P"]:
        """(P,) int: cells whose deformed trilinear map is inverted, per pose."""
        return np.array([int(inverted_cells(c, self.grid.cell_corners).sum())
                         for c in self.corners])

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures of the capture, as written by ``batch.py capture --json``."""
        heads = self.mesh.heads()
        return {
            "object": self.mesh.name,
            "mode": self.mode,
            "corners_follow": self.corners_follow,
            "triangles": int(len(self.mesh.triangles)),
            "object_size": self.mesh.size,
            "resolution": self.grid.resolution,
            "grid_dims": self.grid.dims.tolist(),
            "voxel_size": self.grid.voxel_size,
            "occupied_voxels": int(len(self.grid.cells)),
            "corners": int(len(self.grid.corners)),
            "poses": len(self.poses),
            "inverted_cells": self.inverted_cells.tolist(),
            "heads": heads,
            "capture_s": self.timings.get("total_s"),
            "timings": self.timings,
            "warnings": list(self.mesh.warnings),
        }
