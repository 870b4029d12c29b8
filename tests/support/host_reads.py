"""Counts the reads of tensor values on the host: on CUDA each one waits for the device to
finish everything queued before it (a host synchronization)."""

import contextlib

import torch

# The Tensor methods that hand a value (or a value-dependent shape) to Python.
READS = ("tolist", "item", "__bool__", "__float__", "__int__", "__index__", "nonzero",
         "numpy", "cpu")


@contextlib.contextmanager
def counting_host_reads():
    """Within the block, every call of a READS method appends its name to the yielded list."""
    reads = []
    originals = {name: getattr(torch.Tensor, name) for name in READS}
    own = {name for name in READS if name in vars(torch.Tensor)}  # the others are inherited

    def counting(name, original):
        def counted(self, *args, **kwargs):
            reads.append(name)
            return original(self, *args, **kwargs)
        return counted

    try:
        for name, original in originals.items():
            setattr(torch.Tensor, name, counting(name, original))
        yield reads
    finally:
        for name, original in originals.items():
            if name in own:
                setattr(torch.Tensor, name, original)
            else:
                delattr(torch.Tensor, name)
