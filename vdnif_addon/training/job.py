"""Training as a job (``worker.WorkerJob``): ``fit.fit_model`` in a worker thread, its
progress records through the job's queue, and cancel, with no Blender data touched (the
Train operator is only glue around this).

The model is written to a temporary file beside the target and moved over it only when the
run completed, or was cancelled after at least one step with ``keep_partial``: a failure, a
crash or (by default) a cancel never replaces the last good model.

Importing this module does not import torch (``fit`` is imported by the worker), so the
UI can show a job's state without it.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..errors import VDNIFError
from ..memory import release_cached_memory
from ..worker import Progress, WorkerJob, duration


def progress_interval(steps: int) -> int:
    """Steps between progress records: about 50 per run (each validates a probe subset)."""
    return max(1, min(100, steps // 50))


@dataclass
class JobState(Progress):
    """What the UI shows of a job. Changed only by ``TrainingJob.poll`` (the UI's thread)."""

    steps: int
    status: str = "running"        # running, completed, cancelled or failed
    step: int = 0
    loss: float | None = None
    eta_s: float | None = None
    samples_per_s: float | None = None
    cancelling: bool = False
    message: str = ""              # the error of a failed job, or what happened
    model: str | None = None             # the model file written, None if none was
    history: list = field(default_factory=list)     # the progress records so far

    def done_of(self) -> tuple[int, int]:
        return self.step, self.steps

    def line(self) -> str:
        """One line for the panel and the status bar."""
        if self.loss is None:
            return self._line(f"step 0/{self.steps}, starting")
        return self._line(f"step {self.step}/{self.steps}, loss {self.loss:.4f}, "
                          f"ETA {duration(self.eta_s)}")


class TrainingJob(WorkerJob):
    """Trains ``variant`` on the dataset folder ``data_dir`` into the model file ``out``: a
    ``worker.WorkerJob`` whose work reads no Blender data (so it needs no reads or feed),
    whose progress records are the training's and whose state is a ``JobState``.

    ``overrides``: NetworkConfig / TrainConfig fields (``steps`` required); ``keep_partial``:
    a cancelled run still writes the network of its last finished step. ``run()`` trains in
    this thread (background mode), ``start()`` in a worker thread; ``poll()``, ``cancel()``,
    ``join()`` are the WorkerJob's.
    """

    def __init__(self, data_dir: str | pathlib.Path, variant: str, out: str | pathlib.Path,
                 overrides: Mapping[str, Any], keep_partial: bool = False) -> None:
        if "steps" not in overrides:
            raise VDNIFError("training settings lack the number of steps")
        super().__init__("training", overrides["steps"], "steps", work=None)
        self.data_dir, self.variant = pathlib.Path(data_dir), variant
        self.out, self.keep_partial = pathlib.Path(out), keep_partial
        self.overrides = {"log_interval": progress_interval(overrides["steps"]), **overrides}
        self.state = JobState(steps=overrides["steps"])

    def _execute(self, source: Any, deliver: Any) -> None:
        """Trains, writes the model and queues the outcome; never raises. Torch's cached GPU
        memory is handed back at the end (a render's Warp allocations need it)."""
        partial = self.out.with_name(f".{self.out.name}.training")
        try:
            self._queue.put(self._fit(partial))
        except VDNIFError as exc:
            self._queue.put(("failed", str(exc)))
        except Exception as exc:   # torch errors end the job, not Blender
            self._queue.put(("failed", f"training failed: {type(exc).__name__}: {exc}"))
        finally:
            if partial.exists():
                partial.unlink()
            release_cached_memory()

    def _fit(self, partial: pathlib.Path) -> tuple[str, dict[str, Any] | int]:
        """Trains into ``partial``, moves it over the model file; the outcome to queue (a
        cancel that keeps the previous model queues its step count). The network and its
        data are released when this returns."""
        from ..threads import use_threads
        from .fit import fit_model

        use_threads()
        self.out.parent.mkdir(parents=True, exist_ok=True)
        result, summary = fit_model(self.data_dir, self.variant, partial, self.overrides,
                                    progress=lambda record: self._queue.put(
                                        ("progress", record)),
                                    cancel=self.cancelled)
        if result.status == "cancelled" and (result.steps == 0 or not self.keep_partial):
            return "cancelled", result.steps
        os.replace(partial, self.out)
        return result.status, dict(summary, model=str(self.out))

    def _apply(self, kind: str, payload: Any) -> None:
        state = self.state
        if kind == "progress":
            # The weighted total holds the learned log-variances and goes negative; the
            # sum of the task losses is what a user reads as "the loss falls".
            state.step, state.loss = payload["step"], sum(payload["losses"].values())
            state.history.append(payload)
            state.eta_s, state.samples_per_s = payload["eta_s"], payload["samples_per_s"]
            return
        state.status, state.cancelling = kind, False
        if kind == "failed":
            state.message = payload
        elif isinstance(payload, int):
            when = ("before the first step" if payload == 0
                    else f"after {payload} steps (partial model dropped)")
            state.step = payload
            state.message = f"cancelled {when}: the previous model is kept"
        else:
            state.model = payload["model"]
            state.step = payload["train"]["steps"]
            state.message = (f"{kind} after {state.step} steps in "
                             f"{duration(payload['train']['seconds'])}")
