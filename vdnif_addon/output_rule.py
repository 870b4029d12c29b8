"""The output rule: an output may replace only a file of its own kind that VDNIF wrote.

A file is VDNIF's by its own mark (a model's format name, a JSON object's ``"format":
"vdnif-..."``, a markdown file's section markers or first line, a PNG's ``Software: VDNIF``
text) or by a mark file in its folder or a folder above (``OUTPUT_MARK``, written into a
folder VDNIF made or found empty for its outputs, ``claim_folder``; a dataset folder's
manifest). Anything else that exists (a .blend, a foreign file, a file the same run reads,
``run_inputs``, a device or FIFO, also through a link, anything in /dev or /proc) is refused
on one line naming the option and the file, and left unchanged; an empty regular file holds
nothing to lose and may be replaced. ``safe_io.atomic_path`` applies the rule to every write.

``all_or_nothing`` makes a run's several files appear together or not at all.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import os
import pathlib
import re
import stat
import threading
import zipfile
import zlib
from typing import BinaryIO, Iterator

from .errors import VDNIFError


def _reason(exc: BaseException) -> str:
    return exc.strerror.lower() if isinstance(exc, OSError) and exc.strerror else str(exc)


OUTPUT_MARK = "vdnif-output.txt"
"""The mark file of a folder VDNIF made, or found empty, for its outputs: the files of
VDNIF's kinds in it (and below it) are VDNIF's to replace."""
OUTPUT_MARK_TEXT = ("VDNIF wrote the files in this folder; it replaces them when it runs "
                    "again.\n")
DATASET_MANIFEST = "vdnif-dataset.manifest"
"""A dataset folder's manifest (``training.dataset``): a folder VDNIF made."""
FOLDER_MARKS = (OUTPUT_MARK, DATASET_MANIFEST)
MARK_KEY = "format"
"""The key of a JSON object's mark, whose value names its kind (``vdnif-...``)."""
REPORT_FORMAT = "vdnif-report"
"""The ``format`` key the batch commands' JSON reports carry: the JSON's own mark."""
MARKDOWN_MARK = "<!-- written by VDNIF; each run rewrites this file whole -->"
"""The first line of a markdown file VDNIF writes whole (a section file is known by its
section markers)."""
PNG_SOFTWARE = b"VDNIF"
"""The PNG text ``Software`` of the images VDNIF writes (``mark_png``)."""

KINDS = {   # kind: (file suffixes, in words)
    "model": ((".vdnif",), "a model file"),
    "json": ((".json",), "a JSON file"),
    "markdown": ((".md",), "a markdown file"),
    "png": ((".png",), "a PNG image"),
    "exr": ((".exr",), "an EXR image"),
    "csv": ((".csv",), "a CSV file"),
    "blend": ((".blend",), "a .blend file"),
    "dataset": ((".npz", ".json", ".manifest"), "a dataset file"),
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


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words ("a folder", "a FIFO", ...)."""
    for test, kind in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a folder"),
                       (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


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


@contextlib.contextmanager
def _open_regular(path: pathlib.Path) -> Iterator[BinaryIO]:
    """``path`` open for reading when it is a regular file (a FIFO is not waited on)."""
    descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise VDNIFError(f"'{path}' is not a regular file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(descriptor, True)
        file = os.fdopen(descriptor, "rb")
    except BaseException:
        os.close(descriptor)
        raise
    with file:
        yield file


def _read_head(path: pathlib.Path, limit: int) -> bytes | None:
    try:
        with _open_regular(path) as file:
            return file.read(limit + 1)
    except (VDNIFError, OSError):
        return None


def _model_mark(path: pathlib.Path) -> bool:
    try:
        with _open_regular(path) as file, zipfile.ZipFile(file) as archive:
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
            f"<!-- end {key} -->" in text for key in re.findall(r"^<!-- ([^<>]+?) -->$", text,
                                                                   re.M))
    try:
        value = json.loads(text)
    except ValueError:
        return False
    return isinstance(value, dict) and str(value.get(MARK_KEY, "")).startswith("vdnif-")


def unmarked(value: dict) -> dict:
    """A JSON object of VDNIF's without its mark: a row gathered into a file of another kind
    (a list, which carries no mark), where the row's own mark would claim the wrong file."""
    return {key: item for key, item in value.items() if key != MARK_KEY}


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
    suffixes, words = KINDS.get(kind, ((), "a file"))
    if path.suffix.lower() in suffixes and (own_mark(path, kind) or (
            not link and folder_marked(path.parent))):
        return
    raise VDNIFError(f"{what} '{path}' exists and is not {words} VDNIF wrote: refusing to "
                     "replace it (remove it or choose another path)")


def check_folder_ours(path: str | os.PathLike, what: str) -> None:
    """Refuses an existing folder ``path`` that holds files but is not VDNIF's (no mark, not
    claimed by this process): an output folder is new, empty, or VDNIF's."""
    path = pathlib.Path(path)
    if not path.is_dir() or folder_marked(path) or claimed(path):
        return
    try:
        foreign = next(os.scandir(path), None)
    except OSError as exc:
        raise VDNIFError(f"{what} '{path}' cannot be read: {_reason(exc)}") from None
    if foreign is not None:
        raise VDNIFError(f"{what} '{path}' holds files VDNIF did not write (such as "
                         f"'{foreign.name}'): give a new or empty folder, or one VDNIF wrote")


def claim(path: str | os.PathLike) -> None:
    """Takes the output folder ``path`` for this process's outputs (``safe_io.claim_folder``
    checks it first): the first file written into it marks it."""
    with _lock:
        _claimed.add(os.path.abspath(path))


def claimed(folder: str | os.PathLike) -> bool:
    """Whether this process took ``folder`` for its outputs (``claim_folder``)."""
    return os.path.abspath(folder) in _claimed


def pending_writes() -> list | None:
    """The files written inside the current ``all_or_nothing`` block, or None outside one:
    ``(temporary, target)`` pairs that ``atomic_path`` leaves for the block to rename."""
    return _pending.get()


def staged_size(paths: list) -> int:
    """Bytes of files just written through ``atomic_path``: at their names, or still under
    their temporary names inside an ``all_or_nothing`` block."""
    staged = {os.path.abspath(target): temporary for temporary, target in
              (pending_writes() or ())}
    return sum(os.stat(staged.get(os.path.abspath(path), path)).st_size for path in paths)


def mark_claimed(folder: pathlib.Path) -> None:
    """Marks the claimed folders that ``folder`` is (or lies in) and lack a mark."""
    folder = pathlib.Path(os.path.abspath(folder))
    for place in (folder, *folder.parents):
        if str(place) in _claimed:
            mark_folder(place)


def mark_folder(folder: str | os.PathLike) -> None:
    """Marks ``folder`` as VDNIF's (``OUTPUT_MARK``) unless it holds a mark already: a
    claimed folder, or the work folder whose lock files VDNIF's runs share."""
    folder = pathlib.Path(folder)
    if not any(os.path.lexists(folder / name) for name in FOLDER_MARKS):
        with contextlib.suppress(FileExistsError):
            descriptor = os.open(folder / OUTPUT_MARK, os.O_WRONLY | os.O_CREAT | os.O_EXCL,
                                 0o666)
            with os.fdopen(descriptor, "w") as file:
                file.write(OUTPUT_MARK_TEXT)


def mark_own(path: str | os.PathLike, kind: str | None) -> None:
    """Gives a file of ``kind`` just written the own mark its writer cannot add (a PNG from
    Blender's or matplotlib's writer: ``mark_png``)."""
    if kind == "png":
        mark_png(path)


def mark_png(path: str | os.PathLike) -> None:
    """Adds the text ``Software: VDNIF`` right after the header of the PNG file ``path``
    (the image's own mark, ``own_mark``); a file that is not a PNG is left as it is."""
    data = pathlib.Path(path).read_bytes()
    signature, ihdr_end = b"\x89PNG\r\n\x1a\n", 8 + 8 + 13 + 4
    if not data.startswith(signature) or data[12:16] != b"IHDR" or \
            b"tEXtSoftware\0" + PNG_SOFTWARE in data[:256]:
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


