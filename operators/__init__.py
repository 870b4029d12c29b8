"""Blender operators (``bpy.ops.vdnif.*``): glue between the UI and the core pipeline.

Each checks in ``poll`` what it needs (the reason is shown when it is unavailable), reports
errors with ``self.report`` and runs synchronously in background mode. torch is imported
only when an operator runs.
"""

import bpy

from . import dependencies, model, passes, presets, scene, training

classes = (*scene.classes, *presets.classes, *training.classes, *passes.classes,
           *model.classes, *dependencies.classes)

register, _unregister = bpy.utils.register_classes_factory(classes)


def unregister():
    training.stop_all()
    _unregister()
