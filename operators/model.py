"""Save Model (a copy of the object's model to a file) and Load Model (a model file checked
against the object, then kept with it like a trained one)."""

import bpy
from bpy_extras.io_utils import ExportHelper, ImportHelper

from .. import storage
from .common import VDNIFOperator

FILE_FILTER = bpy.props.StringProperty(default="*.vdnif", options={"HIDDEN"})


class VDNIF_OT_save_model(VDNIFOperator, bpy.types.Operator, ExportHelper):
    """Save a copy of the object's trained model to a .vdnif file"""

    bl_idname = "vdnif.save_model"
    bl_label = "Save Model"
    needs = ("mesh", "model")
    filename_ext = ".vdnif"
    filter_glob: FILE_FILTER

    def work(self, context, obj):
        storage.export_model(obj, self.filepath)
        return f"'{obj.name}': model saved to {self.filepath}"


class VDNIF_OT_load_model(VDNIFOperator, bpy.types.Operator, ImportHelper):
    """Load a .vdnif model trained on this object at its resolution; keep it with the .blend"""

    bl_idname = "vdnif.load_model"
    bl_label = "Load Model"
    bl_options = {"REGISTER", "UNDO"}       # it changes the object's model and settings
    needs = ("mesh", "torch", "idle")
    filename_ext = ".vdnif"
    filter_glob: FILE_FILTER

    def work(self, context, obj):
        from ..vdnif_addon.blender.steps import model_capture
        from ..vdnif_addon.inference.evaluation import check_model_fits
        from ..vdnif_addon.model.model_file import load_model

        _, metadata = load_model(self.filepath)
        settings = obj.vdnif
        captured = model_capture(obj, metadata, settings.pose_spec())
        check_model_fits(self.filepath, metadata, captured.mesh, captured.grid)
        summary = storage.model_summary(metadata, self.filepath)
        summary[storage.LOADED_FROM] = self.filepath    # Train asks before replacing it
        storage.keep_model(obj, self.filepath, summary)
        settings.adopt(metadata)
        settings.metrics = ""
        return f"'{obj.name}': model {self.filepath} loaded ({storage.model_location(obj)})"


classes = (VDNIF_OT_save_model, VDNIF_OT_load_model)
