"""Every file VDNIF writes goes through here: a fresh temporary file created exclusively in
the target's folder (``tempfile.mkstemp``: a random name, ``O_CREAT | O_EXCL``, so a planted
symlink or an existing file is never opened), renamed over the target with ``os.replace``
only once it is complete. A run that fails leaves the target as it was and no temporary file
behind; a symlink at the target is replaced, never written through.

The output rule (``check_replace``, applied by ``atomic_path`` to every write): an output
may replace only a file of its own kind that VDNIF wrote, known by the file's own mark (a
model's format name, a JSON object's ``"format": "vdnif-..."``, a markdown file's section
markers, a PNG's ``Software: VDNIF`` text) or by a mark file in its folder (``claim_folder``:
a folder VDNIF made, or found empty, for its outputs; a dataset folder's manifest). Anything
else that exists (a .blend, a foreign file, a file the same run reads, ``run_inputs``, a
device or FIFO, also through a link) is refused in one line, unchanged. An empty regular
file holds nothing to lose and may be replaced. ``all_or_nothing`` makes a run's several
files appear together or not at all.

``check_output_file`` / ``check_output_folder`` say before any long work whether an output
place can be written at all, so that a bad ``--json`` or ``--out`` is refused in a second,
not after the training.

``exclusive_lock`` lets processes that share a work folder (``bench`` runs side by side) each
take a different piece of the work.

Reading a file a user names goes through here too: ``open_regular`` refuses a folder, a FIFO
or a device before anything blocks on it or reads it forever, ``check_unpacked`` a zip that
would unpack to more than it holds, and ``check_depth`` / ``first_non_plain`` plain data
(JSON, a model's metadata) that nests too deeply or holds what JSON cannot.
"""

from __future__ import annotations

import contextlib
import contextvars
import io
import json
import math
import numbers
import os
import pathlib
import re
import reprlib
import stat
import tempfile
import threading
import zipfile
import zlib
from typing import Any, BinaryIO, Iterator

from .errors import VDNIFError


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror.lower()
    lines = str(exc).strip().splitlines()
    return lines[0][:200] if lines else type(exc).__name__


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _nearest_existing(path: pathlib.Path) -> pathlib.Path:
    for candidate in (path, *path.parents):
        if os.path.lexists(candidate):
            return candidate
    return pathlib.Path(".")


def _check_creatable(path: pathlib.Path, what: str) -> None:
    """The nearest existing ancestor of ``path`` is a writable folder."""
    existing = _nearest_existing(path)
    if not existing.is_dir():
        raise VDNIFError(f"{what} cannot be written: '{existing}' is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise VDNIFError(f"{what} cannot be written: folder '{existing}' is not writable")


FILE_STEM_LIMIT = 100
"""Longest file-name stem made from a user's name: room for a suffix and the temporary name's
random part within a file system's 255-byte limit."""


def file_stem(text: str) -> str:
    """``text`` (an object's name, a scene's) as one safe file-name component: runs of
    anything but letters, digits, ``_``, ``.`` and ``-`` become ``_``, leading dots go (no
    ``..``, no hidden file), at most FILE_STEM_LIMIT characters; "object" when nothing is
    left. A name never becomes a path: no separator survives."""
    stem = re.sub(r"[^\w.-]+", "_", str(text)).lstrip(".")[:FILE_STEM_LIMIT]
    return stem or "object"


NAME_MAX = 255
"""Longest file name in bytes on the file systems VDNIF writes to (ext4, XFS, APFS, NTFS)."""
_RANDOM_PART = 8                       # mkstemp's random characters
_KEPT_SUFFIX = 16
"""The longest suffix a temporary file keeps (writers such as ``np.savez`` and the image
writers choose their format by it); a longer one is no format."""


def _name_problem(path: pathlib.Path) -> str | None:
    """Why a file or folder name along ``path`` cannot be created, or None."""
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > NAME_MAX:
            return (f"the name '{part[:20]}...' has {size} bytes, more than the file "
                    f"system's {NAME_MAX}")
    return None


def _temporary_affixes(path: pathlib.Path) -> tuple[str, str]:
    """(prefix, suffix) of the temporary file of ``path``: ``.NAME.`` and its suffix, NAME
    cut so that the temporary name fits in ``NAME_MAX`` bytes whenever ``path``'s does."""
    suffix = path.suffix if len(os.fsencode(path.suffix)) <= _KEPT_SUFFIX else ""
    room = NAME_MAX - len("..") - _RANDOM_PART - len(os.fsencode(suffix))
    name = os.fsencode(path.name)[:room].decode("utf-8", "ignore")
    return f".{name}.", suffix


def check_output_folder(path: str | os.PathLike, what: str = "output folder") -> None:
    """Raises VDNIFError unless ``path`` is a folder (existing, or one that can be created)
    in which files can be created."""
    path = pathlib.Path(path)
    if (problem := _name_problem(path)) is not None:     # before a stat fails on it
        raise VDNIFError(f"{what} '{path}' cannot be written: {problem}")
    if os.path.lexists(path) and not path.is_dir():
        raise VDNIFError(f"{what} '{path}' exists and is not a folder")
    if path.is_dir() and not folder_marked(path) and os.path.abspath(path) not in _claimed:
        try:
            foreign = next(os.scandir(path), None)
        except OSError as exc:
            raise VDNIFError(f"{what} '{path}' cannot be read: {_reason(exc)}") from None
        if foreign is not None:
            raise VDNIFError(f"{what} '{path}' holds files VDNIF did not write (such as "
                             f"'{foreign.name}'): give a new or empty folder, or one VDNIF "
                             "wrote")
    _check_creatable(path, f"{what} '{path}'")


def check_output_file(path: str | os.PathLike, what: str = "output file",
                      kind: str | None = None) -> None:
    """Raises VDNIFError unless a file of ``kind`` (default: by its suffix) can be written
    at ``path``: not a folder, in a folder that exists or can be created and is writable,
    and nothing there that the output rule (``check_replace``) keeps."""
    text = os.fspath(path)
    path = pathlib.Path(path)
    if path.name in ("", ".", "..") or text.replace(os.sep, "/").rpartition("/")[2] in (
            "", ".", ".."):
        raise VDNIFError(f"{what} '{text}' names a folder, not a file")
    if (problem := _name_problem(path)) is not None:     # before a stat fails on it
        raise VDNIFError(f"{what} '{path}' cannot be written: {problem}")
    if path.is_dir():
        raise VDNIFError(f"{what} '{path}' is a folder, not a file")
    check_replace(path, what, kind)
    _check_creatable(path.parent if str(path.parent) else pathlib.Path("."),
                     f"{what} '{path}'")


# --------------------------------------------------------------------------- the output rule

OUTPUT_MARK = "vdnif-output.txt"
"""The mark file of a folder VDNIF made, or found empty, for its outputs: the files of
VDNIF's kinds in it (and below it) are VDNIF's to replace."""
OUTPUT_MARK_TEXT = ("VDNIF wrote the files in this folder; it replaces them when it runs "
                    "again.\n")
DATASET_MANIFEST = "vdnif-dataset.manifest"
"""A dataset folder's manifest (``training.dataset``): a folder VDNIF made."""
FOLDER_MARKS = (OUTPUT_MARK, DATASET_MANIFEST)
REPORT_FORMAT = "vdnif-report"
"""The ``format`` key the batch commands' JSON reports carry: the JSON's own mark."""
MARKDOWN_MARK = "<!-- written by VDNIF; each run rewrites this file whole -->"
"""The first line of a markdown file VDNIF writes whole (a section file is known by its
section markers)."""
PNG_SOFTWARE = b"VDNIF"
"""The PNG text ``Software`` of the images VDNIF writes (``mark_png``)."""

KINDS = {   # kind: (file suffixes, in words)
    "model": ((".vdnif",), "model file"),
    "json": ((".json",), "JSON file"),
    "markdown": ((".md",), "markdown file"),
    "png": ((".png",), "PNG image"),
    "exr": ((".exr",), "EXR image"),
    "csv": ((".csv",), "CSV file"),
    "blend": ((".blend",), ".blend file"),
    "dataset": ((".npz", ".json", ".manifest"), "dataset file"),
}
DEVICE_FOLDERS = ("/dev", "/proc", "/sys")
"""Folders of devices and kernel state: /dev/stdout is a link there, and replacing it (root
may) would break the machine's standard output, so nothing is written in them."""
_MODEL_FORMAT = b"vdnif-model"          # model_file.FORMAT_NAME, in the archive's pickle
_MARK_BYTES = 64 << 20                  # a JSON or markdown file larger is not read for a mark

_inputs: list[tuple[pathlib.Path, str]] = []
_force = [False]
_claimed: set[str] = set()
_lock = threading.Lock()
_pending: contextvars.ContextVar[list | None] = contextvars.ContextVar("vdnif_pending",
                                                                       default=None)


def kind_of(path: str | os.PathLike) -> str | None:
    """The kind (``KINDS``) of a file by its suffix, or None."""
    suffix = pathlib.Path(path).suffix.lower()
    return next((kind for kind, (suffixes, _) in KINDS.items() if suffix in suffixes), None)


@contextlib.contextmanager
def run_inputs(paths: list[tuple[str | os.PathLike, str]], force: bool = False) -> Iterator[None]:
    """For the block, the files a run reads (``(path, label)``: "the model file") are
    refused as outputs; a model among them may be replaced by a model only with ``force``
    (``--force``)."""
    with _lock:
        saved = list(_inputs), _force[0]
        _inputs[:] = [(pathlib.Path(path), label) for path, label in paths]
        _force[0] = force
    try:
        yield
    finally:
        with _lock:
            _inputs[:], _force[0] = saved


def note_input(path: str | os.PathLike, label: str) -> None:
    """Adds a file the run reads, found once its work began (a model a .blend's object
    keeps), to those of ``run_inputs``."""
    with _lock:
        _inputs.append((pathlib.Path(path), label))


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _read_head(path: pathlib.Path, limit: int) -> bytes | None:
    try:
        with open_regular(path, str(path)) as file:
            return file.read(limit + 1)
    except (VDNIFError, OSError):
        return None


def _model_mark(path: pathlib.Path) -> bool:
    try:
        with open_regular(path, str(path)) as file, zipfile.ZipFile(file) as archive:
            for info in archive.infolist():
                if info.filename.endswith("data.pkl") and info.file_size < (1 << 20):
                    return _MODEL_FORMAT in archive.read(info)
    except (VDNIFError, OSError, zipfile.BadZipFile, ValueError, EOFError, RuntimeError):
        pass
    return False


def _text_mark(path: pathlib.Path, kind: str) -> bool:
    data = _read_head(path, _MARK_BYTES)
    if data is None or len(data) > _MARK_BYTES:
        return False
    text = data.decode("utf-8", "replace")
    if kind == "markdown":
        return text.startswith(MARKDOWN_MARK) or any(
            f"<!-- end {key} -->" in text for key in re.findall(r"^<!-- ([\w.-]+) -->$", text,
                                                                   re.M))
    try:
        value = json.loads(text)
    except ValueError:
        return False
    return isinstance(value, dict) and str(value.get("format", "")).startswith("vdnif-")


def _png_mark(path: pathlib.Path) -> bool:
    head = _read_head(path, 256) or b""
    return b"tEXtSoftware\0" + PNG_SOFTWARE in head


def own_mark(path: str | os.PathLike, kind: str) -> bool:
    """Whether the file ``path`` carries VDNIF's own mark of ``kind`` (see the module)."""
    path = pathlib.Path(path)
    if kind == "model":
        return _model_mark(path)
    if kind in ("json", "markdown"):
        return _text_mark(path, kind)
    if kind == "png":
        return _png_mark(path)
    if kind == "dataset" and path.suffix == ".json":
        return _text_mark(path, "json")
    return False


def folder_marked(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` or a folder above it holds a mark of a folder VDNIF made."""
    folder = pathlib.Path(os.path.abspath(folder))
    return any(os.path.isfile(place / name) and not os.path.islink(place / name)
               for place in (folder, *folder.parents) for name in FOLDER_MARKS)


def check_replace(path: str | os.PathLike, what: str, kind: str | None = None) -> None:
    """The output rule: raises VDNIFError, naming ``what`` and ``path``, unless writing a
    file of ``kind`` (default: by the suffix) at ``path`` creates it, or replaces an empty
    regular file or a file of the same kind that VDNIF wrote (its own mark, or a marked
    folder) that this run does not read. Not a regular file (a device, a FIFO, also
    through a link) is refused."""
    path = pathlib.Path(path)
    kind = kind or kind_of(path)
    folder = os.path.realpath(path.parent if str(path.parent) else ".")
    if os.name == "posix" and any(folder == place or folder.startswith(place + "/")
                                  for place in DEVICE_FOLDERS):
        raise VDNIFError(f"{what} '{path}' is in '{folder}', a folder of devices, not of "
                         "files: VDNIF writes only regular files")
    if not os.path.lexists(path):
        return
    try:
        mode, size = (info := os.stat(path)).st_mode, info.st_size
    except FileNotFoundError:           # a dangling link: replaced, never written through
        return
    except OSError as exc:
        raise VDNIFError(f"{what} '{path}' cannot be checked: {_reason(exc)}") from None
    if stat.S_ISDIR(mode):
        raise VDNIFError(f"{what} '{path}' is a folder, not a file")
    if not stat.S_ISREG(mode):
        raise VDNIFError(f"{what} '{path}' is {file_kind(mode)}, not a regular file: VDNIF "
                         "writes only regular files")
    for source, label in list(_inputs):
        if _same_file(path, source):
            if kind == "model" and kind_of(source) == "model" and _force[0]:
                return
            hint = (" (give --force to replace it)" if kind == "model"
                    and kind_of(source) == "model" else "")
            raise VDNIFError(f"{what} '{path}' is {label} this run reads: refusing to "
                             f"replace it{hint}")
    link = os.path.islink(path)
    if size == 0 and not link:
        return
    suffixes, words = KINDS.get(kind, ((), "file"))
    if path.suffix.lower() in suffixes and (own_mark(path, kind) or (
            not link and folder_marked(path.parent))):
        return
    raise VDNIFError(f"{what} '{path}' exists and is not a {words} VDNIF wrote: refusing to "
                     "replace it (remove it or choose another path)")


def claim_folder(path: str | os.PathLike, what: str = "output folder") -> None:
    """Checks the output folder ``path`` (``check_output_folder``) and takes it for this
    process's outputs: the first file written into it marks it (``OUTPUT_MARK``). A folder
    that holds files, none of VDNIF's marks among them, is refused."""
    check_output_folder(path, what)
    with _lock:
        _claimed.add(os.path.abspath(path))


def _mark_claimed(folder: pathlib.Path) -> None:
    """Marks the claimed folders that ``folder`` is (or lies in) and lack a mark."""
    folder = pathlib.Path(os.path.abspath(folder))
    for place in (folder, *folder.parents):
        if str(place) in _claimed and not any(
                os.path.lexists(place / name) for name in FOLDER_MARKS):
            with contextlib.suppress(FileExistsError):
                descriptor = os.open(place / OUTPUT_MARK, os.O_WRONLY | os.O_CREAT | os.O_EXCL,
                                     0o666)
                with os.fdopen(descriptor, "w") as file:
                    file.write(OUTPUT_MARK_TEXT)


def mark_png(path: str | os.PathLike) -> None:
    """Adds the text ``Software: VDNIF`` right after the header of the PNG file ``path``
    (the image's own mark, ``own_mark``); a file that is not a PNG is left as it is."""
    data = pathlib.Path(path).read_bytes()
    signature, ihdr_end = b"\x89PNG\r\n\x1a\n", 8 + 8 + 13 + 4
    if not data.startswith(signature) or data[12:16] != b"IHDR" or b"tEXtSoftware" in \
            data[:256]:
        return
    body = b"tEXt" + b"Software\0" + PNG_SOFTWARE
    chunk = (len(body) - 4).to_bytes(4, "big") + body + zlib.crc32(body).to_bytes(4, "big")
    pathlib.Path(path).write_bytes(data[:ihdr_end] + chunk + data[ihdr_end:])


@contextlib.contextmanager
def all_or_nothing() -> Iterator[None]:
    """Within the block, files written through ``atomic_path`` stay temporary; they take
    their names together when the block ends without an exception, else all are removed:
    a run that writes several files leaves either all new ones or all old ones."""
    pending: list[tuple[str, pathlib.Path]] = []
    token = _pending.set(pending)
    try:
        yield
        for temporary, path in pending:
            os.replace(temporary, path)
        pending.clear()
    except OSError as exc:
        raise VDNIFError(f"cannot write '{pending[0][1] if pending else ''}': "
                         f"{_reason(exc)}") from exc
    finally:
        _pending.reset(token)
        for temporary, _ in pending:
            with contextlib.suppress(OSError):
                os.unlink(temporary)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, what: str = "file",
                make_folder: bool = True, kind: str | None = None) -> Iterator[str]:
    """Yields the name of a fresh empty temporary file beside ``path`` (same suffix, so that
    writers that pick a format by suffix keep it) for a writer that needs a file name; when
    the block ends without an exception it becomes ``path`` (inside ``all_or_nothing``: when
    that block ends), else it is removed. A file of ``kind`` (default: by the suffix) that
    the output rule keeps (``check_replace``) is refused before anything is written.

    The folder is created when missing unless ``make_folder`` is false. Any failure (a full
    disk, a read-only folder, a failing writer) raises VDNIFError naming ``what`` and
    ``path``; the target is then left as it was.
    """
    path = pathlib.Path(path)
    folder = path.parent if str(path.parent) else pathlib.Path(".")
    if (problem := _name_problem(path)) is not None:
        raise VDNIFError(f"cannot write {what} '{path}': {problem}")
    if path.is_dir():
        raise VDNIFError(f"cannot write {what} '{path}': it is a folder")
    check_replace(path, what, kind)
    prefix, suffix = _temporary_affixes(path)
    pending = _pending.get()
    try:
        if make_folder:
            folder.mkdir(parents=True, exist_ok=True)
        _mark_claimed(folder)
        handle, temporary = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=folder)
    except OSError as exc:
        raise VDNIFError(f"cannot write {what} '{path}': {_reason(exc)}") from exc
    try:
        os.fchmod(handle, 0o666 & ~_umask())     # mkstemp makes it private; outputs are not
        os.close(handle)
        yield temporary
        with open(temporary, "rb+") as file:     # durable before it takes the target's name
            os.fsync(file.fileno())
        if pending is None:
            os.replace(temporary, path)
        else:
            pending.append((temporary, path))
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        if isinstance(exc, OSError):
            raise VDNIFError(f"cannot write {what} '{path}': {_reason(exc)}") from exc
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes, what: str = "file",
                       kind: str | None = None) -> pathlib.Path:
    """Writes ``data``, a file of ``kind`` (default: by the suffix), to ``path`` through a
    temporary file (see ``atomic_path``)."""
    with atomic_path(path, what, kind=kind) as temporary:
        with open(temporary, "wb") as file:
            file.write(data)
    return pathlib.Path(path)


def write_text_atomic(path: str | os.PathLike, text: str, what: str = "file",
                      kind: str | None = None) -> pathlib.Path:
    return write_bytes_atomic(path, text.encode("utf-8"), what, kind)


def first_non_finite(value: Any, where: str = "") -> str | None:
    """The JSON path of the first NaN or infinite float in plain data, or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (where or "value")
    if isinstance(value, dict):
        for key, item in value.items():
            found = first_non_finite(item, f"{where}.{key}" if where else str(key))
            if found:
                return found
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            found = first_non_finite(item, f"{where}[{i}]")
            if found:
                return found
    return None


def json_text(data: Any, what: str, indent: int = 2) -> str:
    """``data`` as strict JSON text (no NaN or Infinity, which JSON does not have): a
    non-finite figure raises VDNIFError naming its key."""
    bad = first_non_finite(data)
    if bad is not None:
        raise VDNIFError(f"{what}: the figure '{bad}' is not a finite number (NaN or "
                         "infinite); nothing was written")
    try:
        return json.dumps(data, indent=indent, allow_nan=False) + "\n"
    except (TypeError, ValueError) as exc:
        raise VDNIFError(f"{what}: cannot be written as JSON: {_reason(exc)}") from exc


def write_json_atomic(path: str | os.PathLike, data: Any, what: str = "JSON file",
                      indent: int = 2, kind: str = "json") -> pathlib.Path:
    """Writes ``data`` as strict JSON to ``path`` atomically (a JSON file whatever the
    suffix, for the output rule)."""
    return write_text_atomic(path, json_text(data, f"{what} '{path}'", indent), what, kind)


def exclusive_lock(path: str | os.PathLike) -> io.BufferedRandom | None:
    """The open lock file ``path`` when this process gets its exclusive lock (a context
    manager: closing the file releases it), else None while another open file holds it.
    The operating system drops the lock when its process ends, however it ends, so a
    stopped run leaves no stale lock; the file itself stays (removing a locked file would
    let a third process lock a new file of the same name)."""
    file = open(path, "a+b")
    try:
        if os.name == "nt":
            import msvcrt
            file.seek(0)
            msvcrt.locking(file.fileno(), msvcrt.LK_NBLCK, 1)
        else:
            import fcntl
            fcntl.flock(file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        file.close()
        return None
    return file


# --------------------------------------------------------------------------- reading


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words ("a folder", "a FIFO", ...)."""
    for test, kind in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a folder"),
                       (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


def check_input_file(path: str | os.PathLike, label: str) -> None:
    """Refuses ``path`` on one line that starts with ``label`` and the path ("mesh file
    'x.obj'") unless it is a regular file: checked before any heavy import, so a mistyped
    name fails at once."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise VDNIFError(f"{label} '{path}' does not exist") from None
    except OSError as exc:
        raise VDNIFError(f"{label} '{path}' cannot be read: {_reason(exc)}") from None
    if not stat.S_ISREG(mode):
        raise VDNIFError(f"{label} '{path}' is {file_kind(mode)}, not a file")


def open_regular(path: str | os.PathLike, label: str) -> BinaryIO:
    """``path`` opened for reading in binary, refused on one line that starts with
    ``label`` (what and which file, e.g. "model file m.vdnif") unless it is a regular file:
    a FIFO would block the reader forever and a device such as /dev/zero never ends, so the
    file is opened without blocking and checked before anything reads it."""
    try:
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise VDNIFError(f"{label} does not exist") from None
    except OSError as exc:
        raise VDNIFError(f"{label} cannot be read: {_reason(exc)}") from None
    try:
        mode = os.fstat(descriptor).st_mode
        if not stat.S_ISREG(mode):
            raise VDNIFError(f"{label} is not a regular file: it is {file_kind(mode)}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(descriptor, True)
        return os.fdopen(descriptor, "rb")
    except BaseException:
        os.close(descriptor)
        raise


def unpacked_size(file: BinaryIO) -> int | None:
    """The bytes the zip archive ``file`` unpacks to by its directory (what a reader
    allocates), or None when it is not a zip archive; ``file`` is left at its start."""
    try:
        with zipfile.ZipFile(file) as archive:
            return sum(info.file_size for info in archive.infolist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        return None
    finally:
        file.seek(0)


class _ShortRepr(reprlib.Repr):
    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() > 128:        # str() of an int of over 4300 digits raises
            return f"<an integer of {x.bit_length()} bits>"
        return super().repr_int(x, level)


_SHORT = _ShortRepr()
_SHORT.maxstring = _SHORT.maxother = 60


def shown(value: Any) -> str:
    """``repr(value)`` for a one-line message, kept short: a damaged file's huge list,
    string or integer is cut, never written out whole (nor fails to be)."""
    return _SHORT.repr(value)


MAX_DEPTH = 16
"""Nesting of VDNIF's plain data (a dataset header, a model's metadata; a lattice pose is 6
deep in either): deeper is not VDNIF's, and is refused before anything walks it
recursively."""


def check_depth(data: Any, where: str) -> None:
    """Raises VDNIFError naming ``where`` when the plain data ``data`` nests more than
    ``MAX_DEPTH`` lists or mappings (walked without recursion)."""
    stack = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        items = (value.values() if isinstance(value, dict)
                 else value if isinstance(value, (list, tuple)) else None)
        if items is None:
            continue
        if depth > MAX_DEPTH:
            raise VDNIFError(f"{where}: nests more than {MAX_DEPTH} levels of lists and "
                             "objects")
        stack.extend((item, depth + 1) for item in items)


def finite_number(value: Any) -> bool:
    """Whether ``value`` is a real number (not a bool) that a float holds finitely."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:                   # an integer beyond the float range
        return False


def first_non_plain(value: Any) -> str | None:
    """The JSON path of the first entry of ``value`` that is not finite JSON data (text,
    a finite number, true/false, null, a list, an object with text keys), or None. Call
    after ``check_depth``."""
    stack = [(value, "")]
    while stack:
        item, where = stack.pop()
        if isinstance(item, dict):
            if not all(isinstance(key, str) for key in item):
                return where or "value"
            stack.extend((child, f"{where}.{key}" if where else key)
                         for key, child in reversed(item.items()))
        elif isinstance(item, (list, tuple)):
            stack.extend((child, f"{where}[{i}]") for i, child in reversed(
                list(enumerate(item))))
        elif not (item is None or isinstance(item, (str, bool))
                  or isinstance(item, (int, float)) and finite_number(item)):
            return where or "value"
    return None
