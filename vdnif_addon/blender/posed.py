"""Per-pose geometry of a captured object: the deformed cells with their entry BVH, and the
Blender-evaluated deformed mesh for the true reference."""

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import VDNIFError
from ..kernels import runtime
from ..kernels.cells import DeviceCells
from ..voxels import inverted_cells
from .bvh import BVHCaster
from .deform import CornerDeformer
from .poses import posed
from .read_mesh import evaluated_surface


@dataclass
class PoseGeometry:
    _cells: DeviceCells            # the object's device cells, set to this pose
    corners: np.ndarray            # (C, 3) deformed voxel corners of this pose
    vertices: np.ndarray           # (V, 3) deformed mesh vertices
    normals: np.ndarray            # (T, 3, 3) deformed corner normals
    prepare_s: float               # read the corners, refit the entry BVH, face triangles
    _pose: int = 0                 # the cells' pose count when they were set to this pose
    _mesh_caster: BVHCaster = field(default=None, repr=False)

    @property
    def cells(self):
        """The deformed cells (``DeviceCells``): valid until the next pose of the same
        PosedObject, which moves them."""
        if self._cells.pose != self._pose:
            raise VDNIFError("the cells of this pose were moved to a later pose of the same "
                             "object: take the geometry of one pose at a time")
        return self._cells

    def mesh_caster(self, triangles):
        """BVH over the deformed mesh (built on first use: only references need it)."""
        if self._mesh_caster is None:
            self._mesh_caster = BVHCaster(self.vertices, triangles)
        return self._mesh_caster

    def inverted_cells(self):
        """Number of occupied cells whose deformed trilinear map is inverted."""
        return int(inverted_cells(self.corners, self._cells.grid.cell_corners).sum())


class PosedObject:
    """Poses a captured object one pose at a time. Use as a context manager.

    The device cells (topology and entry BVH) are built once, on ``device`` (a Warp
    device, the network's): a pose copies its deformed corners into them and refits.
    """

    def __init__(self, obj, capture, device="cpu"):
        self.obj, self.capture, self.device = obj, capture, runtime.device(device)
        self.deformer = None
        if capture.mode != "static":
            self.deformer = CornerDeformer(obj, capture.grid.corner_positions())
        self.rest_caster = BVHCaster(capture.mesh.vertices, capture.mesh.triangles)
        self.cells = DeviceCells(capture.grid, self.device)
        self._rest_cells = None

    def geometry(self, pose):
        """PoseGeometry of ``pose`` (a pose dict, see ``poses``; ``{"rest": True}`` is the
        undeformed rest pose). The cells of the previous pose are moved to this one."""
        if pose.get("rest"):
            return self.rest_geometry()
        with posed(pose):
            start = time.perf_counter()
            corners = (self.deformer.deformed() if self.deformer is not None
                       else self.capture.grid.corner_positions())
            self.cells.set_pose(corners)
            prepare_s = time.perf_counter() - start
            vertices, normals = evaluated_surface(self.obj, self.capture.mesh)
        return PoseGeometry(_cells=self.cells, corners=corners, vertices=vertices,
                            normals=normals, prepare_s=prepare_s, _pose=self.cells.pose)

    def rest_geometry(self):
        """PoseGeometry of the undeformed rest pose (rest corners, rest mesh), on cells of
        its own that stay at rest (built on first use)."""
        start = time.perf_counter()
        if self._rest_cells is None:
            self._rest_cells = DeviceCells(self.capture.grid, self.device)
        mesh = self.capture.mesh
        return PoseGeometry(_cells=self._rest_cells,
                            corners=self.capture.grid.corner_positions(),
                            vertices=mesh.vertices, normals=mesh.corner_normals,
                            prepare_s=time.perf_counter() - start,
                            _pose=self._rest_cells.pose)

    def close(self):
        if self.deformer is not None:
            self.deformer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
