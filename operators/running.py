"""The modal glue of every long operator (Train, Generate Dataset, Evaluate, Render Passes,
Render Animation, the estimate): its work runs as one or more stages, each a job in a worker
thread (a ``worker.WorkerJob``; training's is ``training.job.TrainingJob``), with progress
and ETA in the panel and the status bar, Esc or Cancel to stop it, and Blender responsive.
In background mode (batch runs, scripts) the same stages run synchronously.

A window-manager timer ticks the job: on Blender's main thread it reads the poses the
worker needs and writes the images it delivers (Blender's data is touched nowhere else),
then shows the progress. When a stage completes, its ``finish`` keeps the result with the
object (main thread again), an undo step is pushed for what it kept (``common.undo_step``),
and the next stage starts.
"""

from dataclasses import dataclass
from typing import Callable

import bpy

from ..vdnif_addon.errors import VDNIFError
from .common import JOBS, VDNIFOperator, redraw, undo_step

TICK_S = 0.05          # timer interval: reads keep ahead of the worker, Blender stays fluid
_timers = []           # the window-manager timers of running operators


@dataclass
class Stage:
    """One job of an operator: ``make()`` builds it on the main thread (capturing what it
    needs from Blender); ``finish(obj, state)`` keeps its result with ``obj`` and returns the
    message of the outcome, or raises a VDNIFError for a failure. ``undo``: whether
    ``finish`` writes the object's settings or model (then an undo step follows it); a stage
    that writes only images and files does not."""

    make: Callable
    finish: Callable
    undo: bool = True


def handed_over(result):
    """The status of an operator whose work another operator call took over (invoking it
    from a dialog or after an estimate): finished once that one runs."""
    return {"FINISHED"} if result & {"RUNNING_MODAL", "FINISHED"} else {"CANCELLED"}


def outcome(state):
    """Raises the failure of a finished job's state as a VDNIFError."""
    if state.status == "failed":
        raise VDNIFError(state.message)
    return state


class JobOperator(VDNIFOperator):
    """Mixin: ``stages(context, obj)`` lists the Stages; the first failure or cancel ends
    the run (``finish`` still sees it)."""

    def stages(self, context, obj):
        raise NotImplementedError

    def work(self, context, obj):
        """Every stage in this thread: background mode and scripts."""
        message = ""
        for stage in self.stages(context, obj):
            job = stage.make()
            job.run()
            state = job.poll()
            message = stage.finish(obj, state)
            self._kept(obj, stage)
            if state.status != "completed":
                break
        return message

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        return self.start(context)

    def start(self, context):
        """Starts the first stage in a worker; the modal handler follows it."""
        obj = context.active_object
        self._name, self._timer = obj.name, None
        try:
            self._stages = list(self.stages(context, obj))
            self._next(obj)
        except (VDNIFError, OSError) as exc:
            JOBS.pop(self._name, None)
            return self.fail(obj, exc)
        obj.vdnif.last_error = ""
        self._timer = context.window_manager.event_timer_add(TICK_S, window=context.window)
        _timers.append(self._timer)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _next(self, obj):
        self._stage = self._stages.pop(0)
        job = JOBS[obj.name] = self._stage.make()
        job.start()
        return job

    def modal(self, context, event):
        job = JOBS.get(self._name)
        if job is None:                   # the extension is being disabled
            self._stop(context)
            return {"CANCELLED"}
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        obj = bpy.data.objects.get(self._name)
        if obj is None:
            job.cancel()
        try:
            job.tick()
        except (VDNIFError, OSError) as exc:    # writing what the worker delivered failed
            job.cancel()
            self.report({"ERROR"}, str(exc))
        state = job.poll()
        context.workspace.status_text_set(f"VDNIF '{self._name}': {state.line()}"
                                          + ("" if state.done else "  (Esc cancels)"))
        redraw(context)
        if not state.done:
            return {"PASS_THROUGH"}
        job.close()
        if obj is None:
            self._stop(context)
            self.report({"WARNING"}, f"'{self._name}' is gone; its results are not kept")
            return {"CANCELLED"}
        try:
            message = self._stage.finish(obj, state)
            self._kept(obj, self._stage)
            if state.status == "completed" and self._stages:
                self._next(obj)
                return {"PASS_THROUGH"}
        except (VDNIFError, OSError) as exc:
            self._stop(context)
            return self.fail(obj, exc)
        self._stop(context)
        result = self.succeed(obj, message)
        if state.status == "completed":
            self.finished(context, obj)
        return result

    def _kept(self, obj, stage):
        """After a stage's ``finish`` kept its result: the undo step of what it wrote, with
        the error of an earlier run cleared first (it is no longer the object's state)."""
        if stage.undo:
            obj.vdnif.last_error = ""
            undo_step(self.bl_label)

    def finished(self, context, obj):
        """After a completed run, on the main thread (the operator's job is gone)."""

    def cancel(self, context):
        """Blender ends the operator (file loaded, window closed): stop the worker."""
        job = JOBS.get(self._name)
        if job is not None:
            job.cancel()
            job.join()
        self._stop(context)

    def _stop(self, context):
        JOBS.pop(self._name, None)
        if self._timer in _timers:
            _timers.remove(self._timer)
            context.window_manager.event_timer_remove(self._timer)
        if context.workspace is not None:
            context.workspace.status_text_set(None)


class VDNIF_OT_cancel_job(VDNIFOperator, bpy.types.Operator):
    """Stop the running job after its current step; training keeps the previous model
    unless Keep Partial Model on Cancel is on"""

    bl_idname = "vdnif.cancel_job"
    bl_label = "Cancel"
    needs = ("mesh", "running")

    def work(self, context, obj):
        JOBS[obj.name].cancel()
        return f"'{obj.name}': cancelling"


def stop_all():
    """Unregistering: cancels every job and waits for it, removes the timers."""
    for job in JOBS.values():
        job.cancel()
        job.join(timeout=30)
    JOBS.clear()
    for timer in _timers:
        bpy.context.window_manager.event_timer_remove(timer)
    _timers.clear()


classes = (VDNIF_OT_cancel_job,)
