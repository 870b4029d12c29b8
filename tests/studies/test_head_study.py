"""tools/head_study.py: its run syntax, and bad input ending in one error line."""

import pathlib

import pytest
from tool_errors import load_tool, one_error_line

from vdnif_addon.errors import VDNIFError

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "head_study.py"


def test_a_run_names_a_variant_and_its_settings():
    parse = load_tool(TOOL).parse_run
    assert parse("deformed") == ("deformed", {})
    assert parse("proposed:distance_mode=log1p,lr_weighting=0.01") == (
        "proposed", {"distance_mode": "log1p", "lr_weighting": 0.01})
    assert parse("proposed:pe_bands=0") == ("proposed", {"pe_bands": 0})
    with pytest.raises(VDNIFError, match="not KEY=VALUE"):
        parse("proposed:distance_mode")


@pytest.mark.parametrize("arguments, message", [
    (["--data", "{tmp}/missing", "deformed"], "does not exist"),
    (["--data", "{tmp}", "proposed:width"], "not KEY=VALUE"),
])
def test_bad_input_ends_in_one_error_line(tmp_path, arguments, message):
    line = one_error_line(TOOL, [a.format(tmp=tmp_path) for a in arguments])
    assert message in line
