"""What every VDNIF operator shares: poll checks whose reason the user sees, errors
reported with ``self.report`` and kept for the panel, and undo steps for what jobs keep."""

import bpy

from .. import preferences, storage
from ..vdnif_addon.errors import VDNIFError

JOBS = {}   # object name -> its running job (runtime only, never saved), see running


def _mesh(context):
    obj = context.active_object
    if obj is None:
        return "Select a mesh object"
    if obj.type != "MESH":
        return f"'{obj.name}' is a {obj.type.lower()}, not a mesh: select a mesh object"
    if not obj.data.polygons:
        return f"'{obj.name}' has no faces"
    return None


def _torch(_context):
    if not preferences.torch_available():
        return f"PyTorch is not installed: {preferences.INSTALL_HINT}"
    return None


def _idle(context):
    obj = context.active_object
    if obj.name in JOBS:
        return f"'{obj.name}' is busy ({JOBS[obj.name].state.line()}): wait or cancel it"
    return None


def _dataset(context):
    obj = context.active_object
    if not storage.has_dataset(obj):
        return f"'{obj.name}' has no dataset yet: generate one first"
    return None


def _model(context):
    obj = context.active_object
    if not storage.has_model(obj):
        return f"'{obj.name}' has no trained model: train one or load a model file"
    return None


def _running(context):
    obj = context.active_object
    if obj.name not in JOBS:
        return f"'{obj.name}' runs no job"
    return None


CHECKS = {"mesh": _mesh, "torch": _torch, "idle": _idle, "dataset": _dataset,
          "model": _model, "running": _running}


class VDNIFOperator:
    """Mixin: ``needs`` names the CHECKS that must pass (in order; "mesh" first)."""

    needs = ("mesh",)

    @classmethod
    def unavailable(cls, context):
        """Why the operator cannot run now, or None."""
        for need in cls.needs:
            reason = CHECKS[need](context)
            if reason:
                return reason
        return None

    @classmethod
    def poll(cls, context):
        reason = cls.unavailable(context)
        if reason:
            cls.poll_message_set(reason)
        return reason is None

    def execute(self, context):
        """Runs ``self.work(context, obj)`` on the active object; it returns the message
        of success or raises a VDNIFError (or an OSError of a file), which is reported."""
        obj = context.active_object
        try:
            message = self.work(context, obj)
        except (VDNIFError, OSError) as exc:
            return self.fail(obj, exc)
        return self.succeed(obj, message)

    def fail(self, obj, error):
        """Reports ``error`` naming ``obj``, keeps it for the panel; returns CANCELLED."""
        message = str(error)
        if f"'{obj.name}'" not in message:
            message = f"'{obj.name}': {message}"
        obj.vdnif.last_error = message
        self.report({"ERROR"}, message)
        return {"CANCELLED"}

    def succeed(self, obj, message):
        obj.vdnif.last_error = ""
        self.report({"INFO"}, message)
        return {"FINISHED"}


def redraw(context):
    for area in (context.screen.areas if context.screen else ()):
        if area.type in ("VIEW_3D", "IMAGE_EDITOR"):
            area.tag_redraw()


def undo_step(label):
    """Pushes an undo step named ``label`` (the operator's) once a job has written an
    object's settings or its model. Blender's UI pushes one only when an operator with the
    UNDO flag returns, never for what a modal operator writes later from its timer: without
    this step, undoing any later edit would take the job's result away with it. Where
    Blender keeps no undo history (no screen to push from) there is nothing to push to."""
    if bpy.ops.ed.undo_push.poll():
        bpy.ops.ed.undo_push(message=label)
