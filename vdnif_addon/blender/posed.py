"""Per-pose geometry of a captured object: the deformed cells with their entry BVH, and the
Blender-evaluated deformed mesh for the true reference."""

import time
from dataclasses import dataclass, field
from typing import Callable
from functools import cached_property

import numpy as np

from ..groundtruth import rest_surface
from ..kernels.surface import SurfaceCaster
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
    _surface: Callable = field(default=None, repr=False)   # (geometry, triangles) -> caster

    def mesh_caster(self, triangles):
        """The deformed mesh (``triangles`` over this pose's vertices and normals) as a
        SurfaceCaster: one per posed object, built on first use (only references need it)
        and refit to this pose; valid until another pose's ``mesh_caster`` is asked for."""
        return self._surface(self, triangles)

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
        self._deformed, self._deformed_pose = None, None

    @cached_property
    def rest_caster(self):
        """The rest mesh as a SurfaceCaster, for the segments' ground truth (built once)."""
        return rest_surface(self.capture.mesh, self.capture.grid)

    def _deformed_caster(self, geometry, triangles):
        """The deformed mesh's SurfaceCaster, refit to ``geometry``'s pose if it holds
        another: built once per posed object."""
        if self._deformed is None:
            self._deformed = SurfaceCaster(geometry.vertices, triangles, geometry.normals)
        elif self._deformed_pose is not geometry:
            self._deformed.refit(geometry.vertices, geometry.normals)
        self._deformed_pose = geometry
        return self._deformed

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
                            normals=normals, prepare_s=prepare_s,
                            _surface=self._deformed_caster)

    def rest_geometry(self):
        """PoseGeometry of the undeformed rest pose (rest corners, rest mesh)."""
        start = time.perf_counter()
        cells, entry = self._cells(self.capture.grid.corner_positions())
        mesh = self.capture.mesh
        return PoseGeometry(cells=cells, entry_caster=entry, vertices=mesh.vertices,
                            normals=mesh.corner_normals, prepare_s=time.perf_counter() - start,
                            _surface=lambda geometry, triangles: self.rest_caster)

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
