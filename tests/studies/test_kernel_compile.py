"""tools/kernel_compile.py: the first compile of each kernel module, timed in a fresh cache."""

import pathlib

from support.tool_errors import load_tool, one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "kernel_compile.py"
REPO = TOOL.parents[1]


def test_a_round_compiles_every_kernel_module_with_the_packages_options():
    """One round of this checkout for the CPU: a row per kernel module, each compiled into
    the round's own empty cache (seconds and object bytes above zero) with no contraction
    and no adjoints."""
    rows = load_tool(TOOL).compile_round(REPO, 0)
    assert {"walk", "render", "encoder", "dda", "cast", "surface", "cells"} <= set(rows)
    for name, row in rows.items():
        assert row["seconds"] > 0 and row["bytes"] > 0, name
        assert (row["fuse_fp"], row["enable_backward"]) == (False, False), name


def test_bad_options_end_in_one_line(tmp_path):
    assert "--rounds must be at least 1" in one_error_line(TOOL, ["--rounds", "0"])
    line = one_error_line(TOOL, ["--checkout", tmp_path])
    assert str(tmp_path) in line and "holds no vdnif_addon/kernels" in line
