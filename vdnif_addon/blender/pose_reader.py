"""Reads a pose's Blender data (deformed corners, deformed mesh, world matrix, a camera's
view) into a PoseSnapshot. Blender's data may only be read on its main thread: a job reads
its poses here on that thread and hands the snapshots to its worker (``worker``,
``posed.pose_source.PoseFeed``); batch runs read them in their one thread."""

import time

import bpy
import numpy as np

from ..posed.pose_source import PoseSnapshot, PoseSource, register_live_source
from .deform import CornerDeformer
from .poses import posed
from .read_mesh import evaluated_surface


class PoseReader(PoseSource):
    """Poses the live object ``obj`` of ``capture`` and reads it. ``view``: a function of
    no arguments returning the camera's view, read in each pose (None: no view)."""

    host = bpy.app.version_string

    def __init__(self, obj, capture, view=None):
        self.obj, self.capture, self.view = obj, capture, view
        self.name = obj.name
        self.deformer = None
        if capture.mode != "static":
            self.deformer = CornerDeformer(obj, capture.grid.corner_positions(),
                                           capture.corners_follow)

    def read(self, pose):
        start = time.perf_counter()
        with posed(pose):
            snapshot = self.read_current(pose)
        snapshot.read_s = time.perf_counter() - start
        return snapshot

    def read_current(self, pose):
        """The snapshot of the scene as it is now, which is in ``pose`` (the live preview
        reads the frame the user just moved to without setting it again)."""
        start = time.perf_counter()
        corners = (self.deformer.deformed() if self.deformer is not None
                   else self.capture.grid.corner_positions())
        corners_s = time.perf_counter() - start
        vertices, normals = evaluated_surface(self.obj, self.capture.mesh)
        return PoseSnapshot(pose=pose, corners=corners, vertices=vertices, normals=normals,
                            matrix_world=np.array(self.obj.matrix_world, np.float64),
                            corners_s=corners_s, read_s=time.perf_counter() - start,
                            view=None if self.view is None else self.view())

    def close(self):
        if self.deformer is not None:
            self.deformer.close()


register_live_source(PoseReader)
