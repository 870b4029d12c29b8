"""Blender operators (``bpy.ops.vdnif.*``): glue between the UI and the core pipeline.

Each checks in ``poll`` what it needs (the reason is shown when it is unavailable), reports
errors with ``self.report`` and runs synchronously in background mode; long ones run in a
worker otherwise (``running``). torch is imported only when an operator runs.
"""

import bpy

from . import animation, dependencies, model, passes, presets, running, scene, training

classes = (*scene.classes, *presets.classes, *training.classes, *passes.classes,
           *animation.classes, *model.classes, *dependencies.classes, *running.classes)

register, _unregister = bpy.utils.register_classes_factory(classes)


def unregister():
    running.stop_all()
    _unregister()
