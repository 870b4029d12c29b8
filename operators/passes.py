"""Render Passes (this frame, into the pass viewer's images) and Evaluate (metrics on unseen
poses), both in workers (``running``): the poses and the view are read on the main thread,
the network and the references run in the worker."""

import json

import bpy

from .. import storage, viewer
from ..vdnif_addon.text import metrics_line, secondary_line
from .running import JobOperator, Stage, outcome


def model_capture(obj, evaluation_count=None):
    """(the object's model file read, the object captured again as its model was trained on
    it): with ``evaluation_count`` evaluation poses from the object's pose settings,
    disjoint from the poses its model was trained on (``steps.model_capture``)."""
    from ..vdnif_addon.blender.steps import model_capture as capture_for_model
    from ..vdnif_addon.model.model_file import load_model

    loaded = load_model(storage.model_path(obj))
    spec = obj.vdnif.pose_spec()
    return loaded, capture_for_model(obj, loaded[1], spec, evaluation_count is not None,
                                     count=evaluation_count)


def secondary_settings(context, obj):
    """The AO and shadow passes' ``SecondarySettings`` while the object's AO, Shadow or
    Shaded pass toggle is on (the object's AO samples and distance, the scene's light in the
    object's local space and its world as they stand now), else None: they cost rays, so
    they are cast only when asked for. Both are cast together (Shaded needs both,
    ``passes.PASS_NEEDS``); only the toggled ones are written."""
    from ..vdnif_addon.blender.lights import scene_secondary
    from ..vdnif_addon.passes import cast_passes

    if not cast_passes(viewer.secondary_names(obj.vdnif)):
        return None
    # The property holds float32, whose value at the range's ends lies just outside the
    # range the core checks: the decimal the panel shows (7 digits) is the one set.
    distance = float(f"{obj.vdnif.ao_distance:.7g}")
    return scene_secondary(context.scene, obj, samples=obj.vdnif.ao_samples,
                           distance=distance)


def region_3d(context):
    """The RegionView3D of the 3D Viewport the operator runs from, or of the screen's first."""
    if context.space_data is not None and context.space_data.type == "VIEW_3D":
        return context.space_data.region_3d
    for area in (context.screen.areas if context.screen else ()):
        if area.type == "VIEW_3D":
            return area.spaces.active.region_3d
    return None


def render_view(context, obj):
    """(camera, fixed view) the object's settings render through: the scene's camera (read
    in each frame, it may move), or the 3D Viewport's view read now."""
    if obj.vdnif.view == "CAMERA":
        return context.scene.camera, None
    return None, viewer.viewport_view(region_3d(context))


def frames_stage(context, obj, frames, width, height, on_frame, references=False,
                 camera=None, view=None, secondary=None):
    """The ``make`` of a Stage rendering ``frames`` of the object's model
    (``ui_jobs.frames_job``, ``secondary`` its AO and shadow settings);
    ``on_frame(frame, result, captured)`` runs on the main thread for each frame."""
    name, device, precision = obj.name, obj.vdnif.device_name(context), obj.vdnif.precision

    def make():
        from ..vdnif_addon.blender.ui_jobs import frames_job

        obj = bpy.data.objects[name]
        loaded, captured = model_capture(obj)
        return frames_job(obj, captured, storage.model_path(obj), frames, width, height,
                          device, lambda frame, result: on_frame(frame, result, captured),
                          camera=camera, view=view, references=references, loaded=loaded,
                          secondary=secondary, precision=precision)

    return make


class VDNIF_OT_render_passes(JobOperator, bpy.types.Operator):
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

    def stages(self, context, obj):
        settings, scene = obj.vdnif, context.scene
        width, height = viewer.render_size(scene, settings)
        frame = scene.frame_current + scene.frame_subframe
        camera, view = render_view(context, obj)
        kept = {}

        def keep(_frame, result, captured):
            kept.update(result=result, slots=captured.mesh.material_slots)

        make = frames_stage(context, obj, [frame], width, height, keep, references=True,
                            camera=camera, view=view,
                            secondary=secondary_settings(context, obj))

        def finish(obj, state):
            outcome(state)
            if state.status != "completed":
                return f"'{obj.name}': {state.message}"
            result, slots = kept["result"], kept["slots"]   # the material pass: the slots
            viewer.set_view(result.true.with_slots(slots), result.predicted.with_slots(slots),
                            width, height, result.object_size, result.secondary,
                            folder=storage.images_folder(obj), shaded=result.shaded)
            from ..vdnif_addon.output_rule import all_or_nothing
            from ..vdnif_addon.safe_io import claim_folder

            claim_folder(storage.passes_folder(obj), "passes folder")
            with all_or_nothing():          # every file of the render, or none of them
                exr = viewer.write_files(obj, result, slots, width, height, frame,
                                         viewer.secondary_names(obj.vdnif))
            choice = bpy.context.scene.vdnif_viewer
            image = viewer.show(bpy.context, choice)
            where = ("" if viewer.image_editor(bpy.context.screen) is not None
                     else " (open an Image Editor to see it)")
            shown = (f"image '{image.name}'{where}" if image is not None else
                     f"no {viewer.PASS_TITLES[choice.pass_name]} image (its toggle is off)")
            return (f"'{obj.name}' at frame {frame:g}: {int(result.predicted.hit.sum())} "
                    f"of {width * height} pixels hit (reference {int(result.true.hit.sum())}"
                    f"), {shown}; passes written to {storage.portable(exr)}")

        return [Stage(make, finish, undo=False)]      # images and files, no settings


class VDNIF_OT_evaluate(JobOperator, bpy.types.Operator):
    """Evaluate the model on unseen poses against the deformed mesh and the voxel embedding.
    Esc cancels"""

    bl_idname = "vdnif.evaluate"
    bl_label = "Evaluate"
    needs = ("mesh", "torch", "idle", "model")

    def stages(self, context, obj):
        name, settings = obj.name, obj.vdnif
        device = settings.device_name(context)
        secondary = secondary_settings(context, obj)
        width, height = viewer.render_size(context.scene, settings)

        def make():
            from ..vdnif_addon.blender.ui_jobs import evaluation_job

            obj = bpy.data.objects[name]
            settings = obj.vdnif
            loaded, captured = model_capture(obj, settings.eval_poses)
            return evaluation_job(obj, captured, storage.model_path(obj), width, height,
                                  device, loaded, secondary, settings.precision)

        def finish(obj, state):
            outcome(state)
            if state.status != "completed":
                return f"'{obj.name}': {state.message}"
            report = state.result
            obj.vdnif.metrics = json.dumps(report)
            more = (f"; {secondary_line(report['vs_true'])}" if "ao_mae" in report["vs_true"]
                    else "")
            return (f"'{obj.name}': {metrics_line(report['vs_true'])}{more} on "
                    f"{report['poses']} poses")

        return [Stage(make, finish)]


classes = (VDNIF_OT_render_passes, VDNIF_OT_evaluate)
