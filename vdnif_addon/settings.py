"""Defaults that several layers read: one place for each (imports neither torch nor bpy, so
the UI and the command-line parser can read it cheaply)."""

OCCLUSION_THRESHOLD = 0.5
"""Occlusion probability above which a segment counts as a hit, for a model file that holds
no threshold calibrated on held-out poses (files written before calibration existed)."""
