"""Blender operators (``bpy.ops.vdnif.*``): glue between the UI and the core pipeline."""

import bpy

classes = ()

register, unregister = bpy.utils.register_classes_factory(classes)
