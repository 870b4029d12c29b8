"""Where per-pose work gets a pose's Blender data: a ``PoseSource`` hands out
``PoseSnapshot``s, plain arrays read on the thread that may read Blender (its main thread):
a live ``blender.pose_reader.PoseReader`` reads them there, a ``PoseFeed`` passes them from
there to a worker thread. Imports no bpy: the Blender adapter fills these protocols
(``CornerDeformation``, ``PoseSource``) and registers how a live object is read
(``register_live_source``), so the posed stage runs without Blender."""

from dataclasses import dataclass
from typing import Protocol

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


class CornerDeformation(Protocol):
    """Moves the voxel corners as the object's deformers move its mesh in the current pose
    (``blender.deform.CornerDeformer`` evaluates copies of the armature and lattice
    modifiers on them)."""

    def deformed(self) -> np.ndarray:
        """(C, 3) float64: the corners in the object's local deformed space."""


class PoseSource:
    """Where a PosedObject gets each pose's PoseSnapshot."""

    name = ""                      # the object's name, for messages
    deformer = None                # the CornerDeformation of a live source
    host = ""                      # Blender's version where it evaluated (datasets record it)

    def read(self, pose):
        raise NotImplementedError

    def close(self):
        """Removes what reading needed (a live source's helper objects)."""


class PoseFeed(PoseSource):
    """Snapshots read on Blender's main thread for a worker, in the order the worker asks
    for the poses (``worker.Feed``: it raises JobCancelled once the job is cancelled)."""

    def __init__(self, name, cancel, capacity=4, host=""):
        self.name, self.host = name, host
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
        self.host = reader.host

    def read(self, pose):
        return self.calls.call(lambda: self.reader.read(pose))


_live_sources = []


def register_live_source(factory):
    """Makes ``factory(obj, capture)`` (a PoseSource) the reader of live objects handed to
    ``open_source``: the Blender adapter registers its PoseReader when it is imported."""
    _live_sources[:] = [factory]


def open_source(source, capture):
    """(PoseSource, owned): ``source`` itself when it is one, else a live reader of the
    object ``source`` that the caller owns and closes."""
    if isinstance(source, PoseSource):
        return source, False
    if not _live_sources:
        raise VDNIFError(f"'{getattr(source, 'name', source)}' is not a pose source, and no "
                         "Blender adapter is loaded to read it")
    return _live_sources[0](source, capture), True
