"""Sidebar panels of the 3D Viewport (tab "VDNIF")."""

import bpy

from .sidebar import classes

register, unregister = bpy.utils.register_classes_factory(classes)
