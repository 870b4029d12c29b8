"""Every file VDNIF writes goes through here: a fresh temporary file created exclusively in
the target's folder (``tempfile.mkstemp``: a random name, ``O_CREAT | O_EXCL``, so a planted
symlink or an existing file is never opened), renamed over the target with ``os.replace``
only once it is complete. A run that fails leaves the target as it was and no temporary file
behind; a symlink at the target is replaced, never written through.

Every write obeys the output rule (``output_rule.check_replace``): it replaces only a file of
its own kind that VDNIF wrote.

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
import zipfile
from typing import Any, BinaryIO, Iterator

from . import output_rule as rule
from .errors import VDNIFError
from .output_rule import MARKDOWN_MARK, file_kind  # noqa: F401 - MARKDOWN_MARK for writers


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
    rule.check_folder_ours(path, what)
    _check_creatable(path, f"{what} '{path}'")


def claim_folder(path: str | os.PathLike, what: str = "output folder") -> None:
    """Checks the output folder ``path`` and takes it for this process's outputs: the first
    file written into it marks it as VDNIF's (``output_rule``)."""
    check_output_folder(path, what)
    rule.claim(path)


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
    rule.check_replace(path, what, kind)
    _check_creatable(path.parent if str(path.parent) else pathlib.Path("."),
                     f"{what} '{path}'")


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
    rule.check_replace(path, what, kind)
    prefix, suffix = _temporary_affixes(path)
    pending = rule.pending_writes()
    try:
        if make_folder:
            folder.mkdir(parents=True, exist_ok=True)
        rule.mark_claimed(folder)
        handle, temporary = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=folder)
    except OSError as exc:
        raise VDNIFError(f"cannot write {what} '{path}': {_reason(exc)}") from exc
    try:
        os.fchmod(handle, 0o666 & ~_umask())     # mkstemp makes it private; outputs are not
        os.close(handle)
        yield temporary
        rule.mark_own(temporary, kind or rule.kind_of(path))
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
    rule.mark_folder(os.path.dirname(os.path.abspath(path)))   # a work folder runs share
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


ZIP_ERRORS = (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError,
              RuntimeError)
"""What reading a damaged zip archive raises: ``zipfile`` raises NotImplementedError for a
"version needed" or compression method it does not know (one flipped byte) and RuntimeError
for an encrypted member, besides BadZipFile and the I/O errors."""


def unpacked_size(file: BinaryIO, label: str) -> int | None:
    """The bytes the zip archive ``file`` unpacks to by its directory (what a reader
    allocates), or None when it is not a zip archive; ``file`` is left at its start. A zip
    whose directory names a version or method no reader here knows is refused on one line
    starting with ``label`` (what and which file)."""
    try:
        with zipfile.ZipFile(file) as archive:
            return sum(info.file_size for info in archive.infolist())
    except (NotImplementedError, RuntimeError) as exc:
        raise VDNIFError(f"{label} is damaged: its zip archive needs {_reason(exc)}, which "
                         "VDNIF never writes") from None
    except ZIP_ERRORS:
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
