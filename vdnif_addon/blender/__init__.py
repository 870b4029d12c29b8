"""The thin layer that reads, poses and casts Blender scenes (adapters) and the pipeline steps
run on them (``generate``, ``neural``, ``jobs``); the only part of the core that imports bpy
(the studies and the batch commands above it import it too)."""
