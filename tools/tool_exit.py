"""How a tool's script ends: its error as one line and exit status 1, and, once bpy is loaded,
past the interpreter's teardown, where bpy's exit handlers can hang (as ``batch.py`` ends).

    if __name__ == "__main__":
        from tool_exit import run_and_exit

        run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="NAME: error: ")

A script's own folder is first on ``sys.path``; a tool run otherwise (``runpy``) puts
``tools/`` there itself.
"""

import os
import sys


def run_and_exit(main, *args, errors=(), prefix="error: "):
    """Runs ``main(*args)`` and ends the process: status 0, or 1 after ``prefix`` and the
    error on stderr where it raises one of ``errors`` (an exception class or a tuple of
    them; other exceptions and argparse's exits pass through as they are)."""
    code = 0
    try:
        main(*args)
    except errors as error:
        print(f"{prefix}{error}", file=sys.stderr)
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    if "bpy" in sys.modules:
        os._exit(code)
    sys.exit(code)
