"""The Blender adapters: reading meshes, rigs, scenes and poses through bpy, and what drives
them (capture, the pipeline's steps, the UI's jobs); the only part of the core that imports
bpy (the studies and the batch commands above it import it too). What runs on a posed
object without Blender (datasets, the neural render, evaluation, the estimate) is ``posed``.

Importing the package registers the live pose reader with ``posed.pose_source``, so a
posed-stage function handed a live mesh object reads it through Blender."""

from . import pose_reader  # noqa: F401  (registers the live PoseSource)
