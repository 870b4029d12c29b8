"""Sidebar panels of the 3D Viewport (tab "VDNIF")."""

import bpy

classes = ()

register, unregister = bpy.utils.register_classes_factory(classes)
