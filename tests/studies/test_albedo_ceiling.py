"""tools/albedo_ceiling.py: bad input ends in one error line, before any fitting."""

import pathlib

import pytest
from tool_errors import one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "albedo_ceiling.py"
ARM_DATA = pathlib.Path(__file__).resolve().parents[1] / "golden" / "arm-dataset"


@pytest.mark.parametrize("arguments, message", [
    (["--data", "{tmp}/missing"], "does not exist"),
    (["--data", "{tmp}", "--shell", "-0.1"], "--shell must be"),
    (["--data", "{tmp}", "--shell", "nan"], "--shell must be"),
    (["--data", str(ARM_DATA)], "has no albedo head"),    # one material, no texture
])
def test_bad_input_ends_in_one_error_line(tmp_path, arguments, message):
    line = one_error_line(TOOL, [a.format(tmp=tmp_path) for a in arguments])
    assert message in line
