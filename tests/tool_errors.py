"""Shared by the tests of the scripts in tools/: run one with bad input and check that it ends
in one error line."""

import subprocess
import sys


def one_error_line(tool, arguments):
    """Runs the script ``tool`` (a path) with ``arguments``; asserts exit status 1 and a
    single stderr line that names the script, ``NAME: error: ``, and returns that line."""
    done = subprocess.run([sys.executable, str(tool), *map(str, arguments)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{tool.stem}: error: "), done.stderr
    return lines[0]
