"""Where per-pose work gets a pose's Blender data: a ``PoseSource`` hands out
``PoseSnapshot``s, plain arrays read on the thread that may read Blender (its main thread):
a live ``pose_reader.PoseReader`` reads them there, a ``PoseFeed`` passes them from there to
a worker thread. Imports no bpy."""

from dataclasses import dataclass

import numpy as np

from ..errors import VDNIFError
from ..worker import Feed


@dataclass
class PoseSnapshot:
    """What per-pose work needs of the scene in one pose, read on the thread that may read
    Blender: plain arrays, valid whatever Blender does afterwards."""

    pose: dict                     # the pose dict (see ``poses``)
    corners: np.ndarray            # (C, 3) deformed voxel corners, local space
    vertices: np.ndarray           # (V, 3) deformed mesh vertices, local space
    normals: np.ndarray            # (T, 3, 3) deformed corner normals
    matrix_world: np.ndarray       # (4, 4) the object's world matrix in this pose
    corners_s: float               # seconds spent deforming the corners
    read_s: float = 0.0            # seconds of the whole read (posing, corners, mesh)
    view: object = None            # the camera's view in this pose, when one was asked for


class PoseSource:
    """Where a PosedObject gets each pose's PoseSnapshot."""

    name = ""                      # the object's name, for messages
    deformer = None                # the CornerDeformer of a live source

    def read(self, pose):
        raise NotImplementedError

    def close(self):
        """Removes what reading needed (a live source's helper objects)."""


class PoseFeed(PoseSource):
    """Snapshots read on Blender's main thread for a worker, in the order the worker asks
    for the poses (``worker.Feed``: it raises JobCancelled once the job is cancelled)."""

    def __init__(self, name, cancel, capacity=4):
        self.name = name
        self.feed = Feed(cancel, capacity)

    def read(self, pose):
        snapshot = self.feed.get()
        if snapshot.pose != pose:
            raise VDNIFError(f"'{self.name}': the scene was read for pose {snapshot.pose}, "
                             f"not for {pose}")
        return snapshot


class CalledReader(PoseSource):
    """A live ``PoseReader`` used from a worker: each read runs on the main thread through
    ``calls`` (``worker.MainCalls``; ``worker.DirectCalls`` in the main thread itself)."""

    def __init__(self, calls, reader):
        self.calls, self.reader, self.name = calls, reader, reader.name

    def read(self, pose):
        return self.calls.call(lambda: self.reader.read(pose))
