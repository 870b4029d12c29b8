"""Batch entry point for every non-UI use of VDNIF.

    blender --background --python vdnif_addon/batch.py -- <command> [options]
    python vdnif_addon/batch.py -- <command> [options]        (with the bpy module)

``python vdnif_addon/batch.py -- --help`` lists the commands.
"""

import os
import pathlib
import shutil
import sys
from typing import NoReturn


def _arguments(argv: list[str]) -> list[str]:
    """The arguments after ``--`` (Blender's own come before it), or all of them."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def _leave(code: int) -> NoReturn:
    """Ends the process with ``code`` once stdout and stderr are flushed, without the
    interpreter's exit handlers: bpy's can deadlock on the content of a loaded .blend (a
    driver whose Python expression Blender blocked hung at exit after the results were
    printed), and nothing of ours is left to run."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            code = code or 1          # the output could not be delivered: not a success
    _remove_blender_session_folder()
    os._exit(code)


def _remove_blender_session_folder() -> None:
    """Deletes Blender's session temporary folder (``bpy.app.tempdir``, ``blender_XXXXXX``
    in the system's temporary folder), as Blender's own exit handlers would: ``os._exit``
    skips them, and every batch run left one behind."""
    bpy = sys.modules.get("bpy")
    folder = pathlib.Path(bpy.app.tempdir) if bpy is not None and bpy.app.tempdir else None
    if folder is not None and folder.name.startswith("blender_"):
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    from vdnif_addon.cli import main

    _leave(main(_arguments(sys.argv)))
