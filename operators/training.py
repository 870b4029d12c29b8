"""Train (modal: a worker thread, progress in the panel and the status bar, Esc to cancel;
synchronous in background mode) and Cancel Training."""

import bpy

from .. import storage, viewer
from ..vdnif_addon.errors import VDNIFError
from .common import JOBS, VDNIFOperator, redraw

_timers = []        # the window-manager timers of running Train operators


class VDNIF_OT_train(VDNIFOperator, bpy.types.Operator):
    """Train the network on the dataset; the model is kept with the .blend. Esc cancels"""

    bl_idname = "vdnif.train"
    bl_label = "Train"
    needs = ("mesh", "torch", "idle", "dataset")

    def work(self, context, obj):
        """Trains in this thread: background mode and scripts."""
        job = self._job(context, obj)
        job.run()
        return self._keep(obj, job.poll())

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        obj = context.active_object
        try:
            job = self._job(context, obj)
        except VDNIFError as exc:
            return self.fail(obj, exc)
        obj.vdnif.last_error = ""
        self._name = obj.name
        JOBS[obj.name] = job
        job.start()
        self._timer = context.window_manager.event_timer_add(0.25, window=context.window)
        _timers.append(self._timer)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = JOBS.get(self._name)
        if job is None:                   # the extension is being disabled
            return {"CANCELLED"}
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        state = job.poll()
        context.workspace.status_text_set(f"VDNIF '{self._name}': {state.line()}"
                                          + ("" if state.done else "  (Esc cancels)"))
        redraw(context)
        if not state.done:
            return {"PASS_THROUGH"}
        self._stop(context)
        obj = bpy.data.objects.get(self._name)
        if obj is None:
            self.report({"WARNING"}, f"'{self._name}' is gone; its model is not kept")
            return {"CANCELLED"}
        try:
            return self.succeed(obj, self._keep(obj, state))
        except VDNIFError as exc:
            return self.fail(obj, exc)

    def cancel(self, context):
        """Blender ends the operator (file loaded, window closed): stop the worker."""
        job = JOBS.get(self._name)
        if job is not None:
            job.cancel()
            job.join()
        self._stop(context)

    def _job(self, context, obj):
        from ..vdnif_addon.model.variants import variant_config
        from ..vdnif_addon.training.job import TrainingJob

        settings = obj.vdnif
        variant, _ = settings.chosen_variant()
        made_for = settings.parsed("dataset_info").get("variant", variant)
        deformed = variant_config(variant).deformed_data
        if variant_config(made_for).deformed_data != deformed:
            raise VDNIFError(f"the dataset of '{obj.name}' was generated for the {made_for} "
                             f"variant, which trains on other poses than {variant}: "
                             "generate it again")
        return TrainingJob(storage.dataset_folder(obj), variant,
                           storage.training_target(obj), settings.overrides(context))

    def _keep(self, obj, state):
        """Keeps the model the job wrote with the object; the message of the outcome (with
        the note on the variant choice, if any)."""
        if state.status == "failed":
            raise VDNIFError(state.message)
        if state.model is not None:
            from ..vdnif_addon.model.model_file import load_model

            _, metadata = load_model(state.model)
            storage.keep_model(obj, state.model, storage.model_summary(metadata, state.model))
            obj.vdnif.metrics = ""
            viewer.show_training(bpy.context, obj, state.history)
        variant, note = obj.vdnif.chosen_variant()
        return f"'{obj.name}': {state.message}, variant {variant}" + (
            f" ({note})" if note else "")

    def _stop(self, context):
        JOBS.pop(self._name, None)
        if self._timer in _timers:
            _timers.remove(self._timer)
            context.window_manager.event_timer_remove(self._timer)
        if context.workspace is not None:
            context.workspace.status_text_set(None)


class VDNIF_OT_cancel_training(VDNIFOperator, bpy.types.Operator):
    """Stop training after the current step and keep the network trained so far"""

    bl_idname = "vdnif.cancel_training"
    bl_label = "Cancel Training"
    needs = ("mesh", "training")

    def work(self, context, obj):
        JOBS[obj.name].cancel()
        return f"'{obj.name}': cancelling training"


def stop_all():
    """Unregistering: cancels every job and waits for it, removes the timers."""
    for job in JOBS.values():
        job.cancel()
        job.join(timeout=30)
    JOBS.clear()
    for timer in _timers:
        bpy.context.window_manager.event_timer_remove(timer)
    _timers.clear()


classes = (VDNIF_OT_train, VDNIF_OT_cancel_training)
