"""The stopping rule: training ends once the held-out validation stops improving.

Every ``TrainConfig.log_interval`` steps training validates on its held-out poses (the
training data's own, never the evaluation poses). A validation *improves* when one of the
WATCHED figures falls below its mark by more than ``min_gain`` (relative); the mark then
moves to that value (smaller gains do not move it, so a slow steady decline still counts
once it adds up to ``min_gain``). After ``patience`` validations in a row without an
improvement training has converged and stops before its next update. Every process of a
``torchrun`` launch sees the same validation, so all stop at the same step.
"""

from __future__ import annotations

from collections.abc import Mapping

# The held-out figures the rule watches (errors: lower is better); the occlusion and
# material accuracies enter as their errors, the shares of misclassified segments.
WATCHED = ("occlusion_error", "distance_mae_voxels", "normal_error_deg", "material_error",
           "loss/albedo")


def watched(validation: Mapping[str, float | None]) -> dict[str, float]:
    """The WATCHED figures of one held-out validation (``validation.validate``), as errors."""
    figures = dict(validation)
    if figures.get("occlusion_accuracy") is not None:
        figures["occlusion_error"] = 1.0 - figures["occlusion_accuracy"]
    if figures.get("material_accuracy") is not None:
        figures["material_error"] = 1.0 - figures["material_accuracy"]
    return {key: figures[key] for key in WATCHED if figures.get(key) is not None}


class StoppingRule:
    """Feed it each held-out validation; ``converged_at`` is the step it stopped at."""

    def __init__(self, patience: int, min_gain: float) -> None:
        self.patience, self.min_gain = patience, min_gain
        self.marks: dict[str, float] = {}
        self.stale = 0
        self.converged_at: int | None = None

    def update(self, step: int, validation: Mapping[str, float | None] | None) -> bool:
        """Whether training stops after ``step``, given its validation (None: no held-out
        data, the rule never stops). A patience of 0 turns the rule off."""
        if validation is None or self.patience == 0 or self.converged_at is not None:
            return self.converged_at is not None
        improved = False
        for key, error in watched(validation).items():
            mark = self.marks.get(key)
            if mark is None or error < mark * (1 - self.min_gain):
                self.marks[key] = error
                improved = True
        self.stale = 0 if improved else self.stale + 1
        if self.stale >= self.patience:
            self.converged_at = step
        return self.converged_at is not None
