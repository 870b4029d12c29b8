"""The 3D Viewport sidebar tab "VDNIF": one panel per step, drawn from the active object's
settings. Every state (no torch, no model, training, trained, error) says what to do next;
a button that cannot run shows why under it."""

import textwrap

import bpy

from .. import preferences, storage, viewer
from ..operators import common, live_preview
from ..operators.animation import VDNIF_OT_render_animation
from ..operators.dependencies import VDNIF_OT_install_dependencies
from ..operators.model import VDNIF_OT_load_model, VDNIF_OT_save_model
from ..operators.passes import VDNIF_OT_evaluate, VDNIF_OT_render_passes
from ..operators.presets import VDNIF_OT_apply_preset
from ..operators.running import VDNIF_OT_cancel_job
from ..operators.scene import (
    VDNIF_OT_generate_dataset,
    VDNIF_OT_suggest_resolution,
    VDNIF_OT_voxelize,
)
from ..operators.training import VDNIF_OT_estimate, VDNIF_OT_train, fresh_estimate, needs_dataset
from ..vdnif_addon import declarations as declared
from ..vdnif_addon.inference.metrics import verdict
from ..vdnif_addon.presets import PRESET_NAMES
from ..vdnif_addon.text import EMBREE_NOTE, metrics_line, secondary_line, shaded_line

WRAP = 42   # characters per line of wrapped messages


def button(layout, context, operator, icon="NONE"):
    """The operator's button; under it, why it cannot run now."""
    layout.operator(operator.bl_idname, icon=icon)
    reason = operator.unavailable(context)
    if reason:
        lines(layout, reason, "INFO")


def lines(layout, text, icon="NONE"):
    """``text`` wrapped over several labels (labels do not wrap)."""
    for number, line in enumerate(textwrap.wrap(text, WRAP)):
        layout.label(text=line, icon=icon if number == 0 else "BLANK1")


def properties(layout, data, names):
    column = layout.column(align=True)
    for name in names:
        column.prop(data, name)


class SidebarPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "VDNIF"


class StepPanel(SidebarPanel):
    """A sub-panel of one step, shown for a mesh object."""

    bl_parent_id = "VDNIF_PT_main"

    @classmethod
    def poll(cls, context):
        return common.CHECKS["mesh"](context) is None

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        self.draw_step(layout, context, context.active_object.vdnif)
        # Declared settings placed in this panel without a layout line of their own.
        placed = [rna for rna, (_, panel) in declared.panel_properties().items()
                  if panel.section == self.bl_rna.identifier]
        if placed:
            properties(layout, context.active_object.vdnif, placed)


class VDNIF_PT_main(SidebarPanel, bpy.types.Panel):
    bl_label = "VDNIF"

    def draw(self, context):
        layout = self.layout
        if not preferences.torch_available():
            box = layout.box()
            box.alert = True
            lines(box, "PyTorch is not installed: VDNIF needs it to generate datasets, train "
                       "and render.", "ERROR")
            box.operator(VDNIF_OT_install_dependencies.bl_idname, icon="IMPORT")
            lines(box, f"or install it from {preferences.INSTALL_HINT}.")
        reason = common.CHECKS["mesh"](context)
        if reason:
            lines(layout, reason, "INFO")
            return
        obj = context.active_object
        job = common.JOBS.get(obj.name)
        if job is not None:
            state = f"busy: {job.state.line()}"
        elif storage.has_model(obj):
            info = obj.vdnif.parsed("model_info")
            state = f"trained: {info.get('variant')}, {info.get('steps')} steps"
        else:
            state = "no model yet"
        layout.label(text=f"{obj.name}: {state}", icon="MESH_DATA")
        if job is not None:
            layout.progress(factor=min(max(job.state.fraction, 0.0), 1.0), type="BAR",
                            text=job.state.line())
            layout.operator(VDNIF_OT_cancel_job.bl_idname, icon="CANCEL")
        else:
            draw_train(layout, context, obj)
        if obj.vdnif.last_error:
            box = layout.box()
            box.alert = True
            lines(box, obj.vdnif.last_error, "ERROR")


def draw_train(layout, context, obj):
    """The one Train button, with what a run from scratch will cost when it needs a dataset
    (measured by Estimate) or that the dataset is there already."""
    from ..vdnif_addon.posed.estimate import describe

    row = layout.row(align=True)
    row.scale_y = 1.4
    row.operator(VDNIF_OT_train.bl_idname, icon="PLAY")
    reason = VDNIF_OT_train.unavailable(context)
    if reason:
        lines(layout, reason, "INFO")
        return
    dataset = needs_dataset(obj)
    figures = fresh_estimate(context, obj)
    if figures is not None:
        lines(layout, describe(figures, dataset=dataset), "TIME")
    elif dataset:
        lines(layout, "Generates the dataset first (its size and time are shown before it "
                      "starts)", "INFO")
        layout.operator(VDNIF_OT_estimate.bl_idname, icon="TIME")
    else:
        lines(layout, "Trains on the dataset generated before", "INFO")


class VDNIF_PT_voxels(StepPanel, bpy.types.Panel):
    bl_label = "Voxels and Poses"

    def draw_step(self, layout, context, settings):
        row = layout.row(align=True)
        field = row.row(align=True)
        field.enabled = not settings.resolution_auto      # set by the suggestion while on
        field.prop(settings, "resolution")
        row.prop(settings, "resolution_auto", toggle=True)
        row.operator(VDNIF_OT_suggest_resolution.bl_idname, text="", icon="VIEWZOOM")
        if settings.resolution_info:
            lines(layout, settings.resolution_info)
        layout.prop(settings, "pose_source")
        names = ["pose_count"] + (["seed", "max_angle"] if settings.pose_source == "random"
                                  else [])
        properties(layout, settings, names)
        layout.operator(VDNIF_OT_voxelize.bl_idname, text="Voxelize (Optional)",
                        icon="MESH_GRID")
        reason = VDNIF_OT_voxelize.unavailable(context)
        if reason:
            lines(layout, reason, "INFO")
        if settings.voxel_info:
            lines(layout, settings.voxel_info)


class VDNIF_PT_network(StepPanel, bpy.types.Panel):
    bl_label = "Network"

    def draw_step(self, layout, context, settings):
        row = layout.row(align=True)
        row.label(text="Preset")
        unavailable = VDNIF_OT_apply_preset.unavailable_presets()
        for name in PRESET_NAMES:
            cell = row.row(align=True)
            cell.enabled = name not in unavailable
            cell.operator(VDNIF_OT_apply_preset.bl_idname, text=name.title()).preset = name
        for name in PRESET_NAMES:
            if name in unavailable:
                lines(layout, unavailable[name], "INFO")
        properties(layout, settings, ("variant", "steps", "device"))


class VDNIF_PT_network_advanced(StepPanel, bpy.types.Panel):
    """The network's own settings, which the presets and the variant choose."""

    bl_label = "Advanced"
    bl_parent_id = "VDNIF_PT_network"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_step(self, layout, context, settings):
        layout.label(text="Encoding")
        properties(layout, settings, ("levels", "base_resolution", "log2_table_size",
                                      "feature_dim"))
        bands = layout.row()
        bands.enabled = settings.variant != "auto"     # Automatic: the variant's own bands
        bands.prop(settings, "pe_bands")
        layout.label(text="MLP and Training")
        properties(layout, settings, ("width", "depth", "batch_size"))


class VDNIF_PT_dataset(StepPanel, bpy.types.Panel):
    bl_label = "Dataset"

    def draw_step(self, layout, context, settings):
        layout.prop(settings, "rays_per_pose")
        layout.prop(settings, "dataset_dir")
        button(layout, context, VDNIF_OT_generate_dataset, "FILE_NEW")
        info = settings.parsed("dataset_info")
        if info:
            lines(layout, f"{info['segments']:,} segments ({info['hits']:,} hits) of "
                          f"{info['rays']:,} rays, {info['poses']} poses, resolution "
                          f"{info['resolution']}, for {info['variant']}")


class VDNIF_PT_training(StepPanel, bpy.types.Panel):
    bl_label = "Training and Model"

    def draw_step(self, layout, context, settings):
        obj = context.active_object
        layout.prop(settings, "model_storage")
        layout.prop(settings, "keep_partial_model")
        info = settings.parsed("model_info")
        if storage.has_model(obj) and info:
            lines(layout, f"Model: {storage.model_location(obj)}", "FILE")
            lines(layout, f"{info['variant']} at resolution {info['resolution']}, "
                          f"{info['status']} after {info['steps']} steps")
            if "corners_follow" in info:        # kept before it was recorded: not known here
                lines(layout, f"corners follow: {info['corners_follow']}")
            validation = info.get("validation")
            if validation:
                lines(layout, "held-out poses: distance error "
                              f"{validation['distance_mae_voxels']:.3g} voxels, normal error "
                              f"{validation['normal_error_deg']:.3g} deg")
        elif settings.model_path:
            lines(layout, f"Model file {settings.model_path} is missing", "ERROR")
        plot = viewer.training_image_name(obj)
        if plot in bpy.data.images:
            lines(layout, f"Loss plot: image '{plot}' (Image Editor)", "IMAGE_DATA")
        row = layout.row(align=True)
        row.operator(VDNIF_OT_save_model.bl_idname, icon="EXPORT")
        row.operator(VDNIF_OT_load_model.bl_idname, icon="IMPORT")


class VDNIF_PT_passes(StepPanel, bpy.types.Panel):
    bl_label = "Passes"

    def draw_step(self, layout, context, settings):
        layout.prop(settings, "view")
        layout.prop(settings, "use_scene_size")
        if settings.use_scene_size:
            width, height = viewer.render_size(context.scene, settings)
            layout.label(text=f"{width}x{height} (the scene's output, "
                              f"{context.scene.render.resolution_percentage}%)",
                         icon="IMAGE_DATA")
        else:
            properties(layout, settings, ("image_width", "image_height"))
        layout.prop(settings, "precision")
        draw_secondary(layout, context, settings)
        button(layout, context, VDNIF_OT_render_passes, "RENDER_STILL")
        draw_animation(layout, context, settings)
        choice = context.scene.vdnif_viewer
        layout.use_property_split = False
        layout.row().prop(choice, "pass_name", expand=True)
        layout.row().prop(choice, "source", expand=True)
        if viewer.available(choice.pass_name, choice.source):
            layout.label(text=f"Image: {viewer.image_name(choice.pass_name, choice.source)}"
                         " (Image Editor)", icon="IMAGE_DATA")
        elif choice.pass_name in viewer.TOGGLED_PASSES and choice.pass_name not in (
                viewer.secondary_names(settings)):
            layout.label(text=f"Turn {viewer.PASS_TITLES[choice.pass_name]} on above and "
                              "render", icon="INFO")
        else:
            layout.label(text="Render the passes to fill the images", icon="INFO")


def draw_secondary(layout, context, settings):
    """The AO, Shadow and Shaded pass toggles (on, renders and Evaluate cast their rays and
    write them into each frame's EXR), with the AO settings and the light the shadow rays go
    to while their rays are cast (Shaded casts both: ``passes.PASS_NEEDS``)."""
    from ..vdnif_addon.blender.lights import scene_light
    from ..vdnif_addon.passes import SHADED_PASS, cast_passes

    row = layout.row(heading="Passes")
    for name in viewer.TOGGLED_PASSES:
        row.prop(settings, f"pass_{name}", toggle=True)
    names = viewer.secondary_names(settings)
    cast = cast_passes(names)
    if "ao" in cast:
        properties(layout, settings, ("ao_samples", "ao_distance"))
    if "shadow" in cast:
        layout.label(text=f"Light: {scene_light(context.scene, context.active_object).source}",
                     icon="LIGHT_SUN")
    if SHADED_PASS in names and not set(cast) <= set(names):
        lines(layout, "Shaded casts the AO and shadow rays it is made of; their passes are "
                      "written while their own toggles are on", "INFO")


def draw_animation(layout, context, settings):
    """Render Animation's frame range and folder, and the live preview's toggle."""
    layout.prop(settings, "use_scene_frames")
    if settings.use_scene_frames:
        scene = context.scene
        layout.label(text=f"Frames {scene.frame_start}..{scene.frame_end}, step "
                          f"{scene.frame_step}", icon="TIME")
    else:
        properties(layout, settings, ("frame_start", "frame_end", "frame_step"))
    layout.prop(settings, "frames_dir")
    if not settings.frames_dir:
        folder, prefix = storage.frames_output(context.active_object, context.scene)
        lines(layout, f"To {storage.portable(folder / prefix)}", "FILE_FOLDER")
    button(layout, context, VDNIF_OT_render_animation, "RENDER_ANIMATION")
    row = layout.row(align=True)
    row.prop(settings, "live_preview")
    row.prop(settings, "preview_percent")
    failure = live_preview.error(context.active_object)
    if failure:
        lines(layout, failure, "ERROR")


class VDNIF_PT_evaluation(StepPanel, bpy.types.Panel):
    bl_label = "Evaluation"

    def draw_step(self, layout, context, settings):
        layout.prop(settings, "eval_poses")
        button(layout, context, VDNIF_OT_evaluate, "GRAPH")
        if viewer.secondary_names(settings):
            lines(layout, "With AO, shadow and shaded: a pass toggle is on under Passes",
                  "INFO")
        report = settings.parsed("metrics")
        if not report:
            return
        unseen = "unseen " if report.get("unseen_poses") else ""
        layout.label(text=f"{report['poses']} {unseen}poses, {report['width']}x"
                          f"{report['height']}, {report['variant']}")
        lines(layout, f"Verdict: {verdict(report['vs_true'])}")
        for name, title in (("vs_true", "Against the mesh"),
                            ("vs_embedded", "Against the embedding")):
            box = layout.box()
            box.label(text=title)
            lines(box, metrics_line(report[name]))
            if "ao_mae" in report[name]:
                lines(box, secondary_line(report[name]))
            if "shaded_psnr" in report[name]:
                lines(box, shaded_line(report[name]))
        timings = report.get("timings", {})
        box = layout.box()
        box.label(text="Speed on the same rays")
        speed = timings.get("render_rays_per_s")
        if speed is not None:
            box.label(text=f"Network: {speed:,.0f} rays/s")
        elif report.get("speed_withheld"):
            lines(box, f"Network: n/a, {report['speed_withheld']}", "INFO")
        exact = timings.get("exact_rays_per_s")
        if exact is not None:
            box.label(text=f"Exact (Warp's refit BVH): {exact:,.0f} rays/s")
            lines(box, EMBREE_NOTE)


classes = (VDNIF_PT_main, VDNIF_PT_voxels, VDNIF_PT_network, VDNIF_PT_network_advanced,
           VDNIF_PT_dataset, VDNIF_PT_training, VDNIF_PT_passes, VDNIF_PT_evaluation)
