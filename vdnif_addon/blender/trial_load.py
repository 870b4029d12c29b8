"""A mesh file imported, or a .blend opened, first in a child process with a time and memory
budget, and only then in this one.

Blender's importers and its .blend reader are native code that VDNIF cannot stop from the
inside: a damaged file can make them crash (a segfault ends the process without a word),
allocate gigabytes (a 1 MB gzip .blend reached 4.1 GB), or never finish. In a child process
limited by a timeout and ``resource.setrlimit(RLIMIT_AS)`` (set once bpy is loaded, to what
it holds then plus the budget), each ends in the child, and this process refuses the file on
one line naming it and what happened. The budget grows with the
file (``limits.IMPORT_*``). The child costs the import once more plus starting bpy (1.5 to
2.5 s measured on a loaded 2-core machine; docs/cli.md says so).

Windows has no rlimits: there the child has the time budget only.
"""

import os
import pathlib
import signal
import subprocess
import sys

import bpy

from .. import limits
from ..errors import VDNIFError
from ..mesh_input import check_input

MARK = "VDNIF-TRIAL:"

CHILD = r"""
import os, sys
sys.path.insert(0, sys.argv[-4])
memory, kind, path = int(sys.argv[-3]), sys.argv[-2], sys.argv[-1]


def answer(text):
    # os._exit: bpy's exit handlers can deadlock after a file with a blocked Python
    # driver (batch.py leaves the same way)
    print("VDNIF-TRIAL:", text, flush=True)
    sys.stderr.flush()
    os._exit(0)


try:
    import bpy
    from vdnif_addon.errors import VDNIFError
    from vdnif_addon.blender import mesh_files
    try:
        import resource
        with open("/proc/self/status") as status:
            held = next(int(line.split()[1]) << 10 for line in status
                        if line.startswith("VmSize:"))
    except (ImportError, OSError, StopIteration):
        resource = None                 # no rlimits (Windows) or no /proc: time only
    if resource is not None:            # the budget on top of what bpy holds already
        resource.setrlimit(resource.RLIMIT_AS, (held + memory, held + memory))
    if kind == "mesh":
        bpy.ops.wm.read_homefile(use_empty=True)
        mesh_files.import_mesh(path)
    else:
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
except VDNIFError as exc:
    answer("vdnif: " + str(exc).replace("\n", " "))
except MemoryError:
    answer("memory")
except RuntimeError as exc:
    lines = str(exc).strip().splitlines()
    answer("error: " + (lines[-1] if lines else "RuntimeError"))
answer("ok")
"""


def budget(size):
    """(bytes, seconds) of the budget of loading a file of ``size`` bytes."""
    memory = max(limits.IMPORT_MIN_MEMORY, limits.IMPORT_MEMORY_PER_BYTE * size)
    total = _total_memory()
    if total:
        memory = min(memory, total)
    seconds = limits.IMPORT_MIN_SECONDS + limits.IMPORT_SECONDS_PER_MB * size / 1e6
    return memory, seconds


def _total_memory():
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def _command():
    """How to start a bpy of this Blender: the Blender binary inside Blender, else this
    Python (the bpy module from PyPI, whose ``binary_path`` is empty)."""
    if bpy.app.binary_path:
        return [bpy.app.binary_path, "--background", "--factory-startup", "--python-expr",
                CHILD, "--"]
    return [sys.executable, "-c", CHILD]


def trial_load(kind, path, label, memory=None, seconds=None):
    """Loads ``path`` (``kind`` "mesh": ``mesh_files.import_mesh``, "blend": open it) in a
    child process within ``memory`` bytes and ``seconds`` (default: ``budget`` of its
    size); raises VDNIFError starting with ``label`` and the path when it fails, crashes,
    runs out of its memory or time."""
    path = pathlib.Path(path)
    default_memory, default_seconds = budget(os.stat(path).st_size)
    memory = default_memory if memory is None else memory
    seconds = default_seconds if seconds is None else seconds
    root = str(pathlib.Path(__file__).resolve().parents[2])

    # MALLOC_ARENA_MAX: glibc reserves 64 MB of address space per thread's arena, which
    # RLIMIT_AS would count as if it were used
    process = subprocess.Popen(
        [*_command(), root, str(int(memory)), kind, str(path)], stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
        start_new_session=True, env=dict(os.environ, PYTHONPATH="", MALLOC_ARENA_MAX="2"))
    try:
        output, _ = process.communicate(timeout=seconds)
    except subprocess.TimeoutExpired:
        _stop(process)
        raise VDNIFError(f"{label} '{path}' did not load within {seconds:.3g} s (the time "
                         "budget for a file of its size): it is damaged or names a file "
                         "that never ends") from None
    except BaseException:
        _stop(process)
        raise
    marks = [line for line in output.splitlines() if line.startswith(MARK)]
    result = marks[-1][len(MARK):].strip() if marks else None
    gib = (f"{memory / (1 << 30):.1f} GiB" if memory >= 1 << 30
           else f"{memory / (1 << 20):.0f} MiB")
    if result == "ok":
        return
    if result is not None and result.startswith("vdnif:"):        # VDNIF's own refusal
        raise VDNIFError(result.partition(":")[2].strip())
    if result is not None and result.startswith("error:"):        # Blender's
        raise VDNIFError(f"cannot read {label} '{path}': {result.partition(':')[2].strip()}")
    if result == "memory" or _out_of_memory(output):
        raise VDNIFError(f"{label} '{path}' needs more than {gib} to load (its budget: "
                         f"{limits.IMPORT_MEMORY_PER_BYTE} times its size, at least "
                         f"{limits.IMPORT_MIN_MEMORY >> 30} GiB): it is damaged or unpacks "
                         "to far more than it holds")
    code = process.returncode
    how = (f"signal {signal.Signals(-code).name}" if code < 0 and -code in
           signal.valid_signals() else f"exit code {code}")
    raise VDNIFError(f"{label} '{path}' crashed Blender's reader ({how}, within a budget of "
                     f"{gib}): it is damaged or not a file Blender can read")


def _out_of_memory(output):
    words = ("MemoryError", "out of memory", "Calloc returns null", "Malloc returns null",
             "std::bad_alloc", "Cannot allocate memory")
    return any(word in output for word in words)


def _stop(process):
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError, AttributeError):
        process.kill()
    process.wait()


def check_images(label, path):
    """Every image file the loaded file names (a .blend's, an FBX's textures), checked
    like the files VDNIF opens before anything reads its pixels: Blender reads an image
    only when it is first used, so a FIFO there would block the capture, not the load."""
    for image in bpy.data.images:
        if image.packed_file is not None or image.source not in ("FILE", "SEQUENCE", "MOVIE"):
            continue
        name = bpy.path.abspath(image.filepath, library=image.library)
        if name and os.path.lexists(name):
            check_input(name, f"{label} '{path}': image '{image.name}'")
