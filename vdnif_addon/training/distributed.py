"""This process's place in a ``torchrun`` launch and the device it trains on: the collectives
training needs (maximum, sum, union), each the identity when the process is alone."""

from __future__ import annotations

import datetime
import os
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
import torch.distributed as dist

from ..errors import VDNIFError
from ..limits import GROUP_TIMEOUT_S
from ..settings import BOUNDS, DEVICES

if TYPE_CHECKING:
    from jaxtyping import Shaped


@dataclass
class ProcessGroup:
    """This process's rank among ``world`` processes (world 1 when not launched so);
    ``owns_group``: this process joined the group and must leave it (``close``)."""

    rank: int = 0
    world: int = 1
    owns_group: bool = False
    timeout_s: float = GROUP_TIMEOUT_S

    @property
    def active(self) -> bool:
        return self.world > 1

    @classmethod
    def from_environment(cls, device: torch.device,
                         timeout_s: float = GROUP_TIMEOUT_S) -> ProcessGroup:
        """Joins the group that ``torchrun``'s WORLD_SIZE names (NCCL on CUDA, else gloo),
        waiting at most ``timeout_s`` seconds for the other processes, there and at every
        collective after (torch's own default, 30 minutes, left a rank silent that long)."""
        try:
            world = int(os.environ.get("WORLD_SIZE", "1"))
        except ValueError as exc:
            raise VDNIFError(
                f"environment variable WORLD_SIZE is not an integer: {os.environ['WORLD_SIZE']!r}"
            ) from exc
        if world <= 1:
            return cls()
        check_group_timeout(timeout_s)
        if device.type == "cuda":
            # NCCL's collectives (all_gather_object among them) put their tensors on the
            # current device: without this every rank would use cuda:0.
            torch.cuda.set_device(device)
        owns = not dist.is_initialized()
        if owns:
            where = (f"{os.environ.get('MASTER_ADDR', '?')}:"
                     f"{os.environ.get('MASTER_PORT', '?')}")
            rank = os.environ.get("RANK", "?")
            print(f"train: process {rank} of {world} joins the process group at {where}, "
                  f"waiting at most {timeout_s:g} s for the others", file=sys.stderr,
                  flush=True)
            try:
                dist.init_process_group("nccl" if device.type == "cuda" else "gloo",
                                        timeout=datetime.timedelta(seconds=timeout_s))
            except (ValueError, RuntimeError) as exc:
                if timed_out(exc):
                    raise VDNIFError(
                        f"process {rank} waited {timeout_s:g} s for the other {world - 1} "
                        f"process(es) of WORLD_SIZE={world} to join at {where} and they did "
                        "not: start every rank, or raise --group-timeout") from None
                raise VDNIFError(
                    f"could not join the torchrun process group (WORLD_SIZE={world}): {exc}"
                ) from exc
        return cls(dist.get_rank(), dist.get_world_size(), owns, timeout_s)

    def stalled(self, exc: BaseException) -> VDNIFError | None:
        """The one-line error for ``exc`` when it is a collective's timeout (another process
        stopped, died or fell behind by more than the timeout), else None."""
        if not self.active or not timed_out(exc):
            return None
        return VDNIFError(
            f"process {self.rank} waited {self.timeout_s:g} s for the other "
            f"{self.world - 1} process(es) of the group to reach the same step (gradients, "
            "validation sums or the stop flags) and they did not: one stopped, died or is "
            "slower by more than --group-timeout")

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


_TIMEOUT_WORDING = ("timed out", "timeout", "connection closed by peer",
                    "connection reset by peer")
"""How torch's store, gloo and NCCL word a wait that ran out (a peer stopped or gone)."""


def timed_out(exc: BaseException) -> bool:
    """Whether ``exc`` is torch's error for a process-group wait that ran past its timeout
    or lost its peer."""
    if isinstance(exc, dist.DistStoreError):
        return True
    text = str(exc).lower()
    return isinstance(exc, RuntimeError) and any(words in text for words in _TIMEOUT_WORDING)


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
        kind = "cpu"
        if torch.cuda.is_available():
            problem = _warp_cuda_problem()
            if problem is None:
                kind = "cuda"
            elif _warn_once(problem):
                print(f"vdnif: device auto: {problem}; using the CPU", file=sys.stderr,
                      flush=True)
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise VDNIFError("setting device is 'cuda' but no CUDA device is available")
        problem = _warp_cuda_problem()
        if problem is not None:
            raise VDNIFError(f"setting device is 'cuda' but {problem}")
        return torch.device("cuda", _local_gpu())
    return torch.device("cpu")


_warned: set[str] = set()


def _warn_once(message: str) -> bool:
    """Whether ``message`` is new in this process (said once, not per call)."""
    new = message not in _warned
    _warned.add(message)
    return new


def _warp_cuda_problem() -> str | None:
    """Why Warp, which runs every kernel, cannot use the GPU torch sees (None when it can):
    its wheels need a recent NVIDIA driver (CUDA 13, a Turing or newer GPU)."""
    from ..kernels import runtime

    if runtime.cuda_device_count() > 0:
        return None
    return (f"torch sees a CUDA GPU and Warp {runtime.warp_version()} does not (it needs an "
            "NVIDIA driver for CUDA 13 and a Turing or newer GPU)")


def _local_gpu() -> int:
    """This process's GPU: its LOCAL_RANK among the visible GPUs, or the one GPU a scheduler
    that gives each task its own leaves visible."""
    try:
        rank = int(os.environ.get("LOCAL_RANK", "0"))
    except ValueError:
        raise VDNIFError("environment variable LOCAL_RANK is not an integer: "
                         f"{os.environ['LOCAL_RANK']!r}") from None
    count = torch.cuda.device_count()
    if 0 <= rank < count:
        return rank
    if count == 1:
        return 0
    raise VDNIFError(f"LOCAL_RANK {rank} names no visible GPU ({count} visible): give each "
                     "process one GPU, or as many as the ranks on this machine")


def check_group_timeout(timeout_s: float) -> None:
    """Refuses a process group timeout outside its declared range (``--group-timeout``)."""
    low, high = BOUNDS["group_timeout_s"]
    if (isinstance(timeout_s, bool) or not isinstance(timeout_s, (int, float))
            or not low <= timeout_s <= high):
        raise VDNIFError(f"the process group timeout {timeout_s!r} must be a number of "
                         f"seconds in {low:g}..{high:g}")
