"""Batch entry point for every non-UI use of VDNIF.

    blender --background --python vdnif_addon/batch.py -- <command> [options]
    python vdnif_addon/batch.py -- <command> [options]        (with the bpy module)

``python vdnif_addon/batch.py -- --help`` lists the commands.
"""

import os
import pathlib
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
    os._exit(code)


if __name__ == "__main__":
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    from vdnif_addon.cli import main

    _leave(main(_arguments(sys.argv)))
