"""The optimizer step ``training.train.TrainingStep`` replaced, kept as it was: it read the
non-finite and cancel flags on the host after every backward pass (one wait for the device
per step), the test oracle of the deferred check's weights, error and cancel."""

import torch

from vdnif_addon.errors import VDNIFError
from vdnif_addon.training.distributed import ProcessGroup
from vdnif_addon.training.train import _optimizer


class TrainingStep:
    """One optimizer step: forward, losses, backward, the finite check and the cancel flag
    read at once, Adam, learning-rate decay; returns (cancelled, total loss, task losses)."""

    def __init__(self, objective, config, model=None, group=None):
        self.model = model or objective
        self.group = group or ProcessGroup()
        self.optimizer, self.decay = _optimizer(objective, config)
        self.params = list(objective.parameters())
        self.tasks = list(objective.network.head_sizes)
        self.taken = 0

    def __call__(self, batch, cancel=None):
        total, losses = self.model(batch)
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        grad_norm = torch.nn.utils.get_total_norm(
            [p.grad for p in self.params if p.grad is not None]
        )
        requested = torch.tensor(cancel is not None and cancel.is_set(), device=total.device)
        flags = torch.stack(
            [~(torch.isfinite(total) & torch.isfinite(grad_norm)), requested]
        ).float()
        diverged, cancelled = self.group.max(flags).tolist()
        if diverged:
            detail = ", ".join(
                f"{task}={value:.4g}" for task, value in zip(self.tasks, losses.tolist())
            )
            raise VDNIFError(
                f"training stopped at step {self.taken + 1}: "
                f"the loss or its gradient is not finite ({detail})"
            )
        if cancelled:
            return True, total, losses
        self.optimizer.step()
        self.decay.step()
        self.taken += 1
        return False, total, losses
