"""Training's bookkeeping: the losses and time since the last progress record, the records
themselves (``history``) and the overall throughput."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import torch

if TYPE_CHECKING:
    from jaxtyping import Float


def record_due(step: int, log_interval: int, steps: int) -> bool:
    """Whether step ``step`` (1-based) of ``steps`` ends a reporting window: every
    ``log_interval`` steps and the last."""
    return step % log_interval == 0 or step == steps


class ProgressLog:
    """Sums the losses of each step until a record is due, every ``log_interval`` steps and
    at the last of ``steps``; ``samples_per_step``: segments per step over all processes.

    The sums stay on the training device: reading them back each step would wait for the
    device once per step instead of once per record.
    """

    def __init__(self, tasks: Sequence[str], steps: int, log_interval: int,
                 samples_per_step: int, device: torch.device) -> None:
        self.tasks = list(tasks)
        self.steps = steps
        self.log_interval = log_interval
        self.samples_per_step = samples_per_step
        self.running = torch.zeros(1 + len(self.tasks), device=device)  # total, then tasks
        self.window_steps, self.window_seconds = 0, 0.0
        self.steps_done, self.seconds = 0, 0.0
        self.history: list[dict[str, Any]] = []

    def add(self, total: Float[torch.Tensor, ""], losses: Float[torch.Tensor, " tasks"],
            seconds: float) -> None:
        """One finished step: its total and task losses and the seconds it took."""
        self.steps_done += 1
        self.running += torch.cat([total.detach()[None], losses.detach()])
        self.window_steps += 1
        self.window_seconds += seconds
        self.seconds += seconds

    @property
    def due(self) -> bool:
        """Whether the step just added ends a reporting window."""
        return record_due(self.steps_done, self.log_interval, self.steps)

    def record(self, log_variances: dict[str, float],
               validation: dict[str, float] | None) -> dict[str, Any]:
        """The progress record of the window just ended (appended to ``history``): step,
        steps, mean total and task losses, log-variances, samples/s, ETA seconds and the
        validation metrics; starts the next window."""
        means = (self.running / self.window_steps).tolist()
        rate = self.window_steps * self.samples_per_step / max(self.window_seconds, 1e-9)
        record = {
            "step": self.steps_done,
            "steps": self.steps,
            "total": means[0],
            "losses": dict(zip(self.tasks, means[1:])),
            "log_variances": log_variances,
            "samples_per_s": rate,
            "eta_s": (self.steps - self.steps_done) * self.samples_per_step / rate,
            "validation": validation,
        }
        self.history.append(record)
        self.running.zero_()
        self.window_steps, self.window_seconds = 0, 0.0
        return record

    @property
    def samples_per_s(self) -> float:
        """Segments per second over every step taken, all processes."""
        return self.steps_done * self.samples_per_step / max(self.seconds, 1e-9)
