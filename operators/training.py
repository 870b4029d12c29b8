"""Train: the one button that trains from scratch (the dataset when it is missing or was made
for other settings, then the network), after showing the estimated disk and time; and
Estimate, which measures that estimate. Both run in workers (``running``)."""

import dataclasses
import json

import bpy
from bpy.props import BoolProperty

from .. import storage, viewer
from .running import JobOperator, Stage, handed_over, outcome
from .scene import dataset_settings, dataset_stages, follow_stage, suggested_first


def needs_dataset(obj):
    """Whether training must generate the dataset first: none yet, one the object has no
    record of, or one made for other settings (a dataset without its settings recorded, from
    an older version, counts as made for the current ones unless its variant trains on
    other poses)."""
    info = obj.vdnif.parsed("dataset_info")
    if not info or not storage.has_dataset(obj):
        return True
    if "settings" in info:
        return info["settings"] != dataset_settings(obj)
    from ..vdnif_addon.model.variants import variant_config

    variant, _ = obj.vdnif.chosen_variant()
    made_for = info.get("variant", variant)
    return variant_config(made_for).deformed_data != variant_config(variant).deformed_data


def run_settings(context, obj):
    """Everything an estimate depends on: the dataset's settings and the training's."""
    return {"dataset": dataset_settings(obj), "training": obj.vdnif.overrides(context)}


def fresh_estimate(context, obj):
    """The object's estimate when it was measured for its current settings, else None."""
    kept = obj.vdnif.parsed("estimate_info")
    if kept.get("settings") != json.loads(json.dumps(run_settings(context, obj))):
        return None
    return kept["figures"]


def training_stage(context, obj):
    """Trains on the object's dataset into the model it keeps (``training.job``)."""
    name, overrides = obj.name, obj.vdnif.overrides(context)
    variant, _ = obj.vdnif.chosen_variant()

    def make():
        from ..vdnif_addon.training.job import TrainingJob

        obj = bpy.data.objects[name]
        # With no model yet, a cancelled run keeps what it learned: there is nothing to keep.
        keep = obj.vdnif.keep_partial_model or not storage.has_model(obj)
        return TrainingJob(storage.dataset_folder(obj), variant, storage.training_target(obj),
                           overrides, keep_partial=keep)

    def finish(obj, state):
        outcome(state)
        if state.model is not None:
            from ..vdnif_addon.model.model_file import load_model

            _, metadata = load_model(state.model)
            storage.keep_model(obj, state.model, storage.model_summary(metadata, state.model))
            obj.vdnif.metrics = ""
            viewer.show_training(bpy.context, obj, state.history)
        variant, note = obj.vdnif.chosen_variant()
        return f"'{obj.name}': {state.message}, variant {variant}" + (
            f" ({note})" if note else "")

    return Stage(make, finish)


def kept_choice(context, obj):
    """The FollowChoice the object's fresh estimate (``fresh_estimate``) was measured with,
    for the dataset it estimated; else None (measured again)."""
    if fresh_estimate(context, obj) is None:
        return None
    kept = obj.vdnif.parsed("estimate_info").get("corners_follow")
    if kept is None:
        return None
    from ..vdnif_addon.blender.follow_choice import FollowChoice

    return FollowChoice(**kept)


def estimate_stages(context, obj):
    """Measures what a run from scratch costs (``estimate``), kept in the settings, at the
    resolution that run trains at (suggested first where it is suggested) and with the
    corners following as that run's would (``follow_stage``; the choice is kept with the
    estimate, and the run's dataset takes it from there)."""
    name, made = obj.name, {}

    def make():
        from ..vdnif_addon.blender.capture_scene import capture
        from ..vdnif_addon.blender.ui_jobs import estimate_job

        obj = bpy.data.objects[name]
        # read after the suggestion, which sets the resolution the estimate is measured at
        made["settings"] = settings = run_settings(bpy.context, obj)
        chosen = obj.vdnif
        variant, _ = chosen.chosen_variant()
        captured = capture(obj, chosen.resolution, chosen.pose_spec(), deform_corners=False,
                           follow=made["choice"].follow)
        scratch = storage.user_folder("estimates") / storage.slug(obj)
        return estimate_job(obj, captured, variant, chosen.rays_per_pose, settings["training"],
                            scratch, chosen.seed)

    def finish(obj, state):
        outcome(state)
        if state.status == "completed":
            obj.vdnif.estimate_info = json.dumps({
                "settings": made["settings"], "figures": state.result,
                "corners_follow": dataclasses.asdict(made["choice"])})
        return f"'{obj.name}': {state.message}"

    return [*suggested_first(obj), follow_stage(name, made), Stage(make, finish)]


class VDNIF_OT_estimate(JobOperator, bpy.types.Operator):
    """Measure the disk space and time a training from scratch needs with these settings
    (a few rays and training steps)"""

    bl_idname = "vdnif.estimate"
    bl_label = "Estimate Disk and Time"
    needs = ("mesh", "torch", "idle")

    then_train: BoolProperty(options={"HIDDEN", "SKIP_SAVE"})

    def stages(self, context, obj):
        return estimate_stages(context, obj)

    def finished(self, context, obj):
        if self.then_train and fresh_estimate(context, obj) is not None:
            # Train asked about replacing a loaded model before it handed over to the estimate
            bpy.ops.vdnif.train("INVOKE_DEFAULT", replace_loaded=True)


class VDNIF_OT_train(JobOperator, bpy.types.Operator):
    """Train from scratch: generate the dataset when it is missing or made for other settings
    (its estimated size and time are shown first), then train the network; the model is
    kept with the .blend. Esc cancels"""

    bl_idname = "vdnif.train"
    bl_label = "Train"
    needs = ("mesh", "torch", "idle")

    confirmed: BoolProperty(options={"HIDDEN", "SKIP_SAVE"})
    replace_loaded: BoolProperty(options={"HIDDEN", "SKIP_SAVE"})

    def stages(self, context, obj):
        first = (dataset_stages(context, obj, kept_choice(context, obj))
                 if needs_dataset(obj) else [])
        return first + [training_stage(context, obj)]

    def invoke(self, context, event):
        if bpy.app.background or self.confirmed:
            return super().invoke(context, event)
        obj = context.active_object
        loaded = storage.loaded_model(obj)
        if loaded and not self.replace_loaded:      # the output rule: a model the user chose
            return context.window_manager.invoke_confirm(
                self, event, title="Replace the loaded model?", icon="WARNING",
                message=f"Training replaces the model loaded from {loaded}",
                confirm_text="Train")
        if not needs_dataset(obj):
            return self.start(context)
        if fresh_estimate(context, obj) is None:     # measure it first, then ask again
            return handed_over(bpy.ops.vdnif.estimate("INVOKE_DEFAULT", then_train=True))
        return context.window_manager.invoke_props_dialog(
            self, width=420, title="Generate the dataset and train?", confirm_text="Train")

    def draw(self, context):
        from ..vdnif_addon.posed.estimate import describe

        obj = context.active_object
        figures = fresh_estimate(context, obj)
        layout = self.layout
        if figures is not None:
            layout.label(text=f"Dataset: about {_size(figures)} in "
                              f"{storage.dataset_folder(obj)}", icon="DISK_DRIVE")
            layout.label(text=describe(figures).capitalize(), icon="TIME")

    def execute(self, context):
        if not bpy.app.background and not self.confirmed:     # a dialog's Train button
            if not self.replace_loaded and storage.loaded_model(context.active_object):
                return handed_over(bpy.ops.vdnif.train("INVOKE_DEFAULT", replace_loaded=True))
            return handed_over(bpy.ops.vdnif.train("INVOKE_DEFAULT", confirmed=True))
        return super().execute(context)


def _size(figures):
    from ..vdnif_addon.posed.estimate import size_text

    return size_text(figures["bytes"])


classes = (VDNIF_OT_estimate, VDNIF_OT_train)
