"""Per-pose geometry of a captured object: the deformed cells with their entry BVH, and the
Blender-evaluated deformed mesh for the true reference.

A pose's Blender data (deformed corners, deformed mesh, world matrix) comes from a
``pose_source.PoseSource`` as a ``PoseSnapshot``: read from Blender in the calling thread
(``blender.pose_reader.PoseReader``, made for a live object), or handed over by Blender's main
thread to a worker thread (``PoseFeed``). Everything else here touches no Blender data, so
that the per-pose work can run in a worker while Blender stays responsive (``worker``).
"""

import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np

from ..errors import VDNIFError
from ..geometry.voxels import inverted_cells
from ..kernels import runtime
from ..kernels.cells import DeviceCells
from ..kernels.surface import SurfaceCaster
from ..tracing.groundtruth import rest_surface
from .pose_source import open_source


@dataclass
class PoseGeometry:
    _cells: DeviceCells            # the object's device cells, set to this pose
    corners: np.ndarray            # (C, 3) deformed voxel corners of this pose
    vertices: np.ndarray           # (V, 3) deformed mesh vertices
    normals: np.ndarray            # (T, 3, 3) deformed corner normals
    prepare_s: float               # read the corners, refit the entry BVH, face triangles
    evaluate_s: float = 0.0        # the rest of reading the pose (Blender's evaluation)
    matrix_world: np.ndarray = None    # (4, 4) the object's world matrix in this pose
    view: object = None            # the snapshot's camera view, if it read one
    _pose: int = 0                 # the cells' pose count when they were set to this pose
    _surface: Callable = field(default=None, repr=False)   # (geometry, triangles) -> caster

    @property
    def cells(self):
        """The deformed cells (``DeviceCells``): valid until the next pose of the same
        PosedObject, which moves them."""
        if self._cells.pose != self._pose:
            raise VDNIFError("the cells of this pose were moved to a later pose of the same "
                             "object: take the geometry of one pose at a time")
        return self._cells

    def mesh_caster(self, triangles):
        """The deformed mesh (``triangles`` over this pose's vertices and normals) as a
        SurfaceCaster: one per posed object, built on first use (only references need it)
        and refit to this pose; valid until another pose's ``mesh_caster`` is asked for."""
        return self._surface(self, triangles)

    def inverted_cells(self):
        """Number of occupied cells whose deformed trilinear map is inverted."""
        return int(inverted_cells(self.corners, self._cells.grid.cell_corners).sum())


class PosedObject:
    """Poses a captured object one pose at a time. Use as a context manager.

    ``source``: a PoseSource (its owner closes it), or a live mesh object (read through a
    ``PoseReader`` made here and closed on exit). The device cells (topology and entry
    BVH) are built once, on ``device`` (a Warp device, the network's): a pose copies its
    deformed corners into them and refits.
    """

    def __init__(self, source, capture, device="cpu"):
        source, self._owned = open_source(source, capture)
        self.source, self.capture, self.device = source, capture, runtime.device(device)
        self.name = source.name
        self.cells = DeviceCells(capture.grid, self.device)
        self._rest_cells = None
        self._deformed, self._deformed_pose = None, None

    @property
    def deformer(self):
        """The CornerDeformer of a live source (None for a static object or a feed)."""
        return self.source.deformer

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
        undeformed rest pose). The cells of the previous pose are moved to this one."""
        if pose.get("rest"):
            return self.rest_geometry()
        return self.place(self.source.read(pose))

    def place(self, snapshot):
        """PoseGeometry of a PoseSnapshot (touches no Blender data)."""
        start = time.perf_counter()
        self.cells.set_pose(snapshot.corners)
        if self.device.startswith("cuda"):   # its kernels run asynchronously there
            runtime.init().synchronize_device(self.device)
        prepare_s = snapshot.corners_s + time.perf_counter() - start
        return PoseGeometry(_cells=self.cells, corners=snapshot.corners,
                            vertices=snapshot.vertices, normals=snapshot.normals,
                            prepare_s=prepare_s,
                            evaluate_s=max(snapshot.read_s - snapshot.corners_s, 0.0),
                            matrix_world=snapshot.matrix_world,
                            view=snapshot.view, _pose=self.cells.pose,
                            _surface=self._deformed_caster)

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
                            _pose=self._rest_cells.pose,
                            _surface=lambda geometry, triangles: self.rest_caster)

    def close(self):
        if self._owned:
            self.source.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
