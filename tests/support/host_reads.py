"""Counts the reads of device values on the host, torch's and Warp's: on CUDA each one waits
for the device to finish everything queued before it (a host synchronization).

A read is counted by the code path, whatever the device: on the CPU the same call reads host
memory without waiting, but on CUDA it would wait, so a test on the CPU counts what a CUDA
run would stall on. ``wp.to_torch`` and ``wp.from_torch`` share memory and read nothing."""

import contextlib
import threading

import torch
import warp as wp

# The Tensor methods that hand a value (or a value-dependent shape) to Python.
READS = ("tolist", "item", "__bool__", "__float__", "__int__", "__index__", "nonzero",
         "numpy", "cpu")

# Warp's: ``numpy`` (``list`` and ``str`` go through it), NumPy's implicit conversion of a CPU
# array (``np.asarray``: on CUDA there is none), and copies to the host (``to``, ``wp.copy``).
WARP_READS = ("numpy", "__array_interface__", "to", "copy")


def _on_host(device):
    return device is None or wp.get_device(device).is_cpu


@contextlib.contextmanager
def counting_host_reads():
    """Within the block, every torch READS call and every Warp read (WARP_READS, named
    ``warp.<name>``) appends its name to the yielded list; a read inside another (Warp's
    ``numpy`` copies with ``to``) counts once."""
    reads = []
    originals = {name: getattr(torch.Tensor, name) for name in READS}
    own = {name for name in READS if name in vars(torch.Tensor)}  # the others are inherited
    inside = threading.local()

    def counting(name, original, counts=lambda *args, **kwargs: True):
        def counted(*args, **kwargs):
            outer = not getattr(inside, "depth", 0)
            if outer and counts(*args, **kwargs):
                reads.append(name)
            inside.depth = getattr(inside, "depth", 0) + 1
            try:
                return original(*args, **kwargs)
            finally:
                inside.depth -= 1
        return counted

    array = wp.array
    warp_originals = {"numpy": vars(array)["numpy"], "to": vars(array)["to"],
                      "__array_interface__": vars(array)["__array_interface__"],
                      "copy": wp.copy, "to_torch": wp.to_torch, "from_torch": wp.from_torch}
    interface = warp_originals["__array_interface__"]
    patched = {
        "numpy": counting("warp.numpy", warp_originals["numpy"]),
        "to": counting("warp.to", warp_originals["to"],
                       lambda self, device, *a, **k: _on_host(device)
                       and not _on_host(self.device)),
        "__array_interface__": property(counting("warp.__array_interface__", interface.fget,
                                                  lambda self: _on_host(self.device))),
        "copy": counting("warp.copy", warp_originals["copy"],
                         lambda dest, src, *a, **k: _on_host(dest.device)
                         and not _on_host(src.device)),
        # shared memory, no read (on the CPU through the array interface)
        "to_torch": counting("", warp_originals["to_torch"], lambda *args, **kwargs: False),
        "from_torch": counting("", warp_originals["from_torch"], lambda *args, **kwargs: False),
    }
    try:
        for name, original in originals.items():
            setattr(torch.Tensor, name, counting(name, original))
        for name in ("numpy", "to", "__array_interface__"):
            setattr(array, name, patched[name])
        for name in ("copy", "to_torch", "from_torch"):
            setattr(wp, name, patched[name])
        yield reads
    finally:
        for name, original in originals.items():
            if name in own:
                setattr(torch.Tensor, name, original)
            else:
                delattr(torch.Tensor, name)
        for name in ("numpy", "to", "__array_interface__"):
            setattr(array, name, warp_originals[name])
        for name in ("copy", "to_torch", "from_torch"):
            setattr(wp, name, warp_originals[name])
