"""Render Animation: the passes of a frame range (the scene's by default) as image sequences
at the scene's output path and size (unless the panel overrides them), in a worker
(``running``): each frame's pose and camera are read on the main thread, rendered in the
worker, and its images written on the main thread again. With the AO or Shadow pass toggle
on, as for Render Passes, those passes go into every frame's EXR too (toward the light as it
stands when the render starts)."""

import bpy

from .. import storage, viewer
from .passes import VDNIF_OT_render_passes, frames_stage, render_view, secondary_settings
from .running import JobOperator, Stage, outcome


def animation_frames(scene, settings):
    """The frames Render Animation renders: the scene's range and step, or the object's."""
    from ..vdnif_addon.posed.animation import frame_range

    if settings.use_scene_frames:
        return frame_range(scene.frame_start, scene.frame_end, scene.frame_step)
    return frame_range(settings.frame_start, settings.frame_end, settings.frame_step)


class VDNIF_OT_render_animation(JobOperator, bpy.types.Operator):
    """Render the passes of every frame of the range into image sequences (passes.0001.exr,
    normal.0001.png, ...) at the scene's output path, or the output folder set here. Esc
    cancels"""

    bl_idname = "vdnif.render_animation"
    bl_label = "Render Animation"
    needs = VDNIF_OT_render_passes.needs

    @classmethod
    def unavailable(cls, context):
        return VDNIF_OT_render_passes.unavailable(context)

    def stages(self, context, obj):
        from ..vdnif_addon.blender.steps import DistanceScale, write_view

        settings = obj.vdnif
        frames = animation_frames(context.scene, settings)
        width, height = viewer.render_size(context.scene, settings)
        folder, prefix = storage.frames_output(obj, context.scene)
        names, scale = viewer.secondary_names(settings), DistanceScale()
        written = []           # the frames whose images were written

        def write(frame, result, captured):
            from ..vdnif_addon.output_rule import all_or_nothing
            from ..vdnif_addon.safe_io import claim_folder

            claim_folder(folder, "frames folder")
            with all_or_nothing():          # every file of the frame, or none of them
                write_view(folder, result, height, width, captured.mesh.material_slots,
                           frame=frame, secondary_names=names, scale=scale, prefix=prefix)
            written.append(frame)

        camera, view = render_view(context, obj)
        make = frames_stage(context, obj, frames, width, height, write, camera=camera,
                            view=view, secondary=secondary_settings(context, obj))

        def finish(obj, state):
            outcome(state)
            return (f"'{obj.name}': {state.message}; {len(written)} of frames {frames[0]}.."
                    f"{frames[-1]} written to {storage.portable(folder / prefix)}")

        return [Stage(make, finish, undo=False)]      # files, no settings


classes = (VDNIF_OT_render_animation,)
