"""Per-pose geometry of a captured object: the deformed cells with their entry BVH, and the
Blender-evaluated deformed mesh for the true reference."""

import time
from dataclasses import dataclass, field

import numpy as np

from ..traverse import DeformedCells
from ..voxels import inverted_cells
from .bvh import BVHCaster
from .deform import CornerDeformer
from .poses import posed
from .read_mesh import evaluated_surface


@dataclass
class PoseGeometry:
    cells: DeformedCells
    entry_caster: BVHCaster
    vertices: np.ndarray           # (V, 3) deformed mesh vertices
    normals: np.ndarray            # (T, 3, 3) deformed corner normals
    prepare_s: float               # deform corners + entry BVH
    _mesh_caster: BVHCaster = field(default=None, repr=False)

    def mesh_caster(self, triangles):
        """BVH over the deformed mesh (built on first use: only references need it)."""
        if self._mesh_caster is None:
            self._mesh_caster = BVHCaster(self.vertices, triangles)
        return self._mesh_caster

    def inverted_cells(self):
        """Number of occupied cells whose deformed trilinear map is inverted."""
        corners = self.cells.corners
        return int(inverted_cells(corners.reshape(-1, 3),
                                  np.arange(8 * len(corners)).reshape(-1, 8)).sum())


class PosedObject:
    """Poses a captured object one pose at a time. Use as a context manager."""

    def __init__(self, obj, capture):
        self.obj, self.capture = obj, capture
        self.deformer = None
        if capture.mode != "static":
            self.deformer = CornerDeformer(obj, capture.grid.corner_positions())
        self.rest_caster = BVHCaster(capture.mesh.vertices, capture.mesh.triangles)

    def geometry(self, pose):
        """PoseGeometry of ``pose`` (a pose dict, see ``poses``; ``{"rest": True}`` is the
        undeformed rest pose)."""
        if pose.get("rest"):
            return self.rest_geometry()
        with posed(pose):
            start = time.perf_counter()
            corners = (self.deformer.deformed() if self.deformer is not None
                       else self.capture.grid.corner_positions())
            cells, entry = self._cells(corners)
            prepare_s = time.perf_counter() - start
            vertices, normals = evaluated_surface(self.obj, self.capture.mesh)
        return PoseGeometry(cells=cells, entry_caster=entry, vertices=vertices,
                            normals=normals, prepare_s=prepare_s)

    def rest_geometry(self):
        """PoseGeometry of the undeformed rest pose (rest corners, rest mesh)."""
        start = time.perf_counter()
        cells, entry = self._cells(self.capture.grid.corner_positions())
        mesh = self.capture.mesh
        return PoseGeometry(cells=cells, entry_caster=entry, vertices=mesh.vertices,
                            normals=mesh.corner_normals, prepare_s=time.perf_counter() - start)

    def _cells(self, corners):
        cells = DeformedCells.build(self.capture.grid, corners)
        return cells, BVHCaster.from_soup(cells.boundary_triangles())

    def close(self):
        if self.deformer is not None:
            self.deformer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
