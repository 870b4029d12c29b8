"""The scene's frame set for VDNIF's own reads (a pose, the rest at the first frame), told
apart from the user's frame changes: the live preview ignores a frame change while
``held``."""

import contextlib
import math

import bpy

_held = []     # one entry per ``at_frame`` in progress


def held():
    """Whether VDNIF has set the scene's frame (its frame changes are not the user's)."""
    return bool(_held)


@contextlib.contextmanager
def at_frame(frame):
    """The scene at ``frame`` (a float: whole frame and subframe) while inside; the frame it
    showed before, after."""
    scene = bpy.context.scene
    shown = scene.frame_current, scene.frame_subframe
    _held.append(frame)
    try:
        whole = math.floor(frame)
        scene.frame_set(int(whole), subframe=frame - whole)
        yield
    finally:
        try:
            scene.frame_set(shown[0], subframe=shown[1])
        finally:
            _held.pop()
