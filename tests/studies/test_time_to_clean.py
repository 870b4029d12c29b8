"""tools/time_to_clean.py: its setting syntax, and bad input ending in one error line."""

import pathlib

import pytest
from tool_errors import load_tool, one_error_line

from vdnif_addon.errors import VDNIFError

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "time_to_clean.py"


def test_a_setting_is_a_key_and_a_json_value():
    parse = load_tool(TOOL).parse_setting
    assert parse("lr_mlp=0.01") == ("lr_mlp", 0.01)
    assert parse("steps=3000") == ("steps", 3000)
    assert parse("weighting_start=zero") == ("weighting_start", "zero")
    for bad in ("lr_mlp", "=3"):
        with pytest.raises(VDNIFError, match="not KEY=VALUE"):
            parse(bad)


@pytest.mark.parametrize("arguments, message", [
    (["--data", "{tmp}/missing", "--scene", "arm", "--json", "{tmp}/x.json"], "does not exist"),
    (["--data", "{tmp}", "--scene", "arm", "--set", "steps", "--json", "{tmp}/x.json"],
     "not KEY=VALUE"),
    (["--data", "{tmp}", "--scene", "arm", "--set", "steps=-1", "--json", "{tmp}/x.json"],
     "steps"),
    (["--data", "{tmp}", "--scene", "arm", "--repeats", "0", "--json", "{tmp}/x.json"],
     "--repeats must be at least 1"),
])
def test_bad_input_ends_in_one_error_line(tmp_path, arguments, message):
    line = one_error_line(TOOL, [a.format(tmp=tmp_path) for a in arguments])
    assert message in line
