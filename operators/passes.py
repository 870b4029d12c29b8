"""Render Passes (into the pass viewer's images) and Evaluate (metrics on unseen poses)."""

import json

import bpy

from .. import storage, viewer
from ..vdnif_addon.text import metrics_line
from .common import VDNIFOperator, progress


def model_capture(obj, evaluation_count=None):
    """(the object's model file read, the object captured again as its model was trained on
    it): with ``evaluation_count`` evaluation poses from the object's pose settings,
    disjoint from the poses its model was trained on (``jobs.model_capture``)."""
    from ..vdnif_addon.blender.jobs import model_capture as capture_for_model
    from ..vdnif_addon.model.model_file import load_model

    loaded = load_model(storage.model_path(obj))
    spec = obj.vdnif.pose_spec()
    return loaded, capture_for_model(obj, loaded[1], spec, evaluation_count is not None,
                                     count=evaluation_count)


def region_3d(context):
    """The RegionView3D of the 3D Viewport the operator runs from, or of the screen's first."""
    if context.space_data is not None and context.space_data.type == "VIEW_3D":
        return context.space_data.region_3d
    for area in (context.screen.areas if context.screen else ()):
        if area.type == "VIEW_3D":
            return area.spaces.active.region_3d
    return None


class VDNIF_OT_render_passes(VDNIFOperator, bpy.types.Operator):
    """Render this frame's passes with the network and the deformed mesh into VDNIF images"""

    bl_idname = "vdnif.render_passes"
    bl_label = "Render Passes"
    needs = ("mesh", "torch", "idle", "model")

    @classmethod
    def unavailable(cls, context):
        reason = super().unavailable(context)
        if reason is None and context.active_object.vdnif.view == "CAMERA" and (
                context.scene.camera is None):
            return "The scene has no active camera: add one or render the viewport's view"
        return reason

    def work(self, context, obj):
        from ..vdnif_addon.blender.neural import camera_rays, load_scene_model, render_rays

        settings, scene = obj.vdnif, context.scene
        width, height = settings.image_width, settings.image_height
        if settings.view == "CAMERA":
            origins, directions = camera_rays(scene.camera, width, height)
        else:
            origins, directions = viewer.view_rays(region_3d(context), width, height)
        loaded, captured = model_capture(obj)
        model = load_scene_model(storage.model_path(obj), captured, settings.device_name(context),
                                 loaded)
        pose = {"frame": scene.frame_current + scene.frame_subframe}
        result = render_rays(obj, captured, model, pose, origins, directions, references=True)
        slots = captured.mesh.material_slots          # the material pass shows the slots
        viewer.set_view(result.true.with_slots(slots), result.predicted.with_slots(slots),
                            width, height, result.object_size)
        exr = viewer.write_files(obj, result, slots, width, height, pose["frame"])
        image = viewer.show(context, scene.vdnif_viewer)
        where = ("" if viewer.image_editor(context.screen) is not None
                 else " (open an Image Editor to see it)")
        return (f"'{obj.name}' at frame {pose['frame']:g}: {int(result.predicted.hit.sum())} "
                f"of {width * height} pixels hit (reference {int(result.true.hit.sum())}), "
                f"image '{image.name}'{where}; passes written to {storage.portable(exr)}")


class VDNIF_OT_evaluate(VDNIFOperator, bpy.types.Operator):
    """Evaluate the model on unseen poses against the deformed mesh and the voxel embedding"""

    bl_idname = "vdnif.evaluate"
    bl_label = "Evaluate"
    needs = ("mesh", "torch", "idle", "model")

    def work(self, context, obj):
        from ..vdnif_addon.blender.jobs import evaluate_file

        settings = obj.vdnif
        loaded, captured = model_capture(obj, settings.eval_poses)
        with progress(context, len(captured.poses)) as update:
            report, _ = evaluate_file(obj, captured, storage.model_path(obj),
                                      settings.image_width, settings.image_height,
                                      settings.device_name(context), progress=update,
                                      loaded=loaded)
        settings.metrics = json.dumps(report)
        return f"'{obj.name}': {metrics_line(report['vs_true'])} on {report['poses']} poses"


classes = (VDNIF_OT_render_passes, VDNIF_OT_evaluate)
