"""Batch entry point for every non-UI use of VDNIF.

    blender --background --python vdnif_addon/batch.py -- <command> [options]
    python vdnif_addon/batch.py -- <command> [options]        (with the bpy module)

``python vdnif_addon/batch.py -- --help`` lists the commands.
"""

import pathlib
import sys


def _arguments(argv):
    """The arguments after ``--`` (Blender's own come before it), or all of them."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


if __name__ == "__main__":
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    from vdnif_addon.commands import main

    code = main(_arguments(sys.argv))
    sys.stdout.flush()
    sys.exit(code)
