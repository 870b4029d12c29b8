"""Shared by the tests of the scripts in tools/: load one as a module, or run one with bad
input and check that it ends in one error line."""

import importlib.util
import pathlib
import subprocess
import sys

FOREIGN = b'{"mine": true}\n'
"""A file VDNIF did not write, where a tool's output is named."""


def load_tool(tool):
    """The script ``tool`` (a path) imported as a module named after it (its ``main`` not
    run), to test its functions."""
    spec = importlib.util.spec_from_file_location(tool.stem, tool)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def one_error_line(tool, arguments):
    """Runs the script ``tool`` (a path) with ``arguments``; asserts exit status 1 and a
    single stderr line that names the script, ``NAME: error: ``, and returns that line."""
    done = subprocess.run([sys.executable, str(tool), *map(str, arguments)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{tool.stem}: error: "), done.stderr
    return lines[0]


def refuses_foreign_output(tool, arguments, foreign, option):
    """Writes FOREIGN at ``foreign``, runs the script ``tool`` with ``arguments`` (which name
    it) and asserts that the output rule refused it in one error line naming ``option`` and
    leaving it as it was, with nothing written beside it; returns the line."""
    foreign = pathlib.Path(foreign)
    foreign.write_bytes(FOREIGN)
    before = sorted(foreign.parent.iterdir())
    line = one_error_line(tool, arguments)
    assert option in line and "refusing to replace it" in line, line
    assert foreign.read_bytes() == FOREIGN
    assert sorted(foreign.parent.iterdir()) == before
    return line
