"""This process's place in a ``torchrun`` launch and the device it trains on: the collectives
training needs (maximum, sum, union), each the identity when the process is alone."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
import torch.distributed as dist

from ..errors import VDNIFError
from ..settings import DEVICES

if TYPE_CHECKING:
    from jaxtyping import Shaped


@dataclass
class ProcessGroup:
    """This process's rank among ``world`` processes (world 1 when not launched so);
    ``owns_group``: this process joined the group and must leave it (``close``)."""

    rank: int = 0
    world: int = 1
    owns_group: bool = False

    @property
    def active(self) -> bool:
        return self.world > 1

    @classmethod
    def from_environment(cls, device: torch.device) -> ProcessGroup:
        """Joins the group that ``torchrun``'s WORLD_SIZE names (NCCL on CUDA, else gloo)."""
        try:
            world = int(os.environ.get("WORLD_SIZE", "1"))
        except ValueError as exc:
            raise VDNIFError(
                f"environment variable WORLD_SIZE is not an integer: {os.environ['WORLD_SIZE']!r}"
            ) from exc
        if world <= 1:
            return cls()
        owns = not dist.is_initialized()
        if owns:
            try:
                dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
            except (ValueError, RuntimeError) as exc:
                raise VDNIFError(
                    f"could not join the torchrun process group (WORLD_SIZE={world}): {exc}"
                ) from exc
        return cls(dist.get_rank(), dist.get_world_size(), owns)

    def close(self) -> None:
        """Leaves the group if this process joined it."""
        if self.owns_group:
            dist.destroy_process_group()

    def max(self, values: Shaped[torch.Tensor, "*shape"]) -> Shaped[torch.Tensor, "*shape"]:
        """Elementwise maximum over processes, in place (identity when alone)."""
        if self.active:
            dist.all_reduce(values, op=dist.ReduceOp.MAX)
        return values

    def sum(self, values: Shaped[torch.Tensor, "*shape"]) -> Shaped[torch.Tensor, "*shape"]:
        """Elementwise sum over processes, in place (identity when alone)."""
        if self.active:
            dist.all_reduce(values)
        return values

    def union(self, items: list[int]) -> list[int]:
        """The sorted union of every process's ``items``."""
        if not self.active:
            return sorted(set(items))
        gathered: list[list[int] | None] = [None] * self.world
        dist.all_gather_object(gathered, items)
        return sorted({item for part in gathered for item in (part or [])})


def resolve_device(kind: str | torch.device) -> torch.device:
    """ "auto" (CUDA if available, else CPU), "cpu" or "cuda" (this process's LOCAL_RANK
    device); ``settings.DEVICES`` names them, and any other name is refused. A torch device
    (one resolved already, by a command that passes it on) is returned as it is, so that
    resolving twice is harmless."""
    if isinstance(kind, torch.device):
        if kind.type not in ("cpu", "cuda"):
            raise VDNIFError(f"unknown device '{kind}': expected a CPU or CUDA device")
        return kind
    if kind not in DEVICES:
        raise VDNIFError(f"unknown device '{kind}': expected one of {', '.join(DEVICES)}")
    if kind == "auto":
        kind = "cuda" if torch.cuda.is_available() else "cpu"
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise VDNIFError("setting device is 'cuda' but no CUDA device is available")
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    return torch.device("cpu")
