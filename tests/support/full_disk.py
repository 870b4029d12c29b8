"""Runs ``batch.py`` as if a disk filled up under one folder:

    python tests/support/full_disk.py FOLDER BYTES -- <command> [options]

Every file that Python opens for writing under FOLDER takes its bytes from one budget of
BYTES; a write past it stores what fits and then fails with ``OSError(ENOSPC)``, as a write
to a full disk does. Files written by native code (torch's own writer, Blender's image
writers) are not affected. The catalogue of bad inputs runs the commands that write through
Python this way (``tests/cli/test_bad_inputs_files.py``).
"""

import builtins
import errno
import io
import os
import runpy
import sys

FOLDER = os.path.realpath(sys.argv[1]) + os.sep
LEFT = [int(sys.argv[2])]
REAL_OPEN = io.open


class FullDiskFile(io.FileIO):
    """A file whose writes draw on the shared budget ``LEFT``."""

    def write(self, data):
        data = memoryview(data).cast("B")
        if not LEFT[0] and len(data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), self.name)
        written = super().write(data[:LEFT[0]])
        LEFT[0] -= written
        return written


def full_disk_open(file, mode="r", buffering=-1, encoding=None, errors=None, newline=None,
                   closefd=True, opener=None):
    writing = any(flag in mode for flag in "wxa+")
    if not (writing and isinstance(file, (str, bytes, os.PathLike))
            and os.path.realpath(file).startswith(FOLDER)):
        return REAL_OPEN(file, mode, buffering, encoding, errors, newline, closefd, opener)
    raw = FullDiskFile(file, "".join(flag for flag in mode if flag in "rwxa+"),
                       closefd=closefd, opener=opener)
    buffered = (io.BufferedRandom if "+" in mode else io.BufferedWriter)(raw)
    if "b" in mode:
        return buffered
    return io.TextIOWrapper(buffered, encoding or "utf-8", errors, newline)


builtins.open = io.open = full_disk_open
batch = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                     "vdnif_addon", "batch.py")
sys.argv = [batch, *sys.argv[3:]]
runpy.run_path(batch, run_name="__main__")
