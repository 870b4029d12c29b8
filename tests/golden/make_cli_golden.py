"""Writes ``cli.json``: the batch CLI's behaviour as users see it, recorded before the CLI
moved out of ``vdnif_addon/commands.py`` into ``vdnif_addon/cli/`` (the commit "before the
move"), so that ``tests/cli/test_cli_golden.py`` can show the move changed nothing. Regenerate
it only for an option or default changed on purpose, and check that the diff touches only
that (``bench --work`` and the recipe's 9,000 steps were such changes); otherwise a later
parser must reproduce it exactly (``record`` reads today's parser, ``vdnif_addon.cli``). Run
from the repository root with the bpy module:

    python tests/golden/make_cli_golden.py

For the top-level parser and every subcommand it holds:
- ``help``: what ``main([..., "--help"])`` prints (80 columns) and its exit code;
- ``parsed``: ``vars(parse_args(MINIMAL[command]))``, values that are not JSON as their repr,
  a function (the command's ``run``) as its name (its module is what the move changes).
"""

import contextlib
import io
import json
import os
import pathlib
import sys

REPO = pathlib.Path(__file__).resolve().parents[2]
GOLDEN = pathlib.Path(__file__).resolve().parent / "cli.json"
COLUMNS = "80"          # argparse wraps --help to $COLUMNS - 2

# The fewest arguments each command parses with (its required ones); "" is the top level.
MINIMAL = {
    "": [],
    "capture": ["capture"],
    "dataset": ["dataset", "--out", "d"],
    "references": ["references"],
    "train": ["train"],
    "render": ["render", "--model", "m.vdnif", "--out", "r"],
    "evaluate": ["evaluate", "--model", "m.vdnif"],
    "demo": ["demo"],
    "experiment": ["experiment", "static"],
    "bench": ["bench"],
    "side-by-side": ["side-by-side"],
    "bench-network": ["bench-network"],
}


def _value(value):
    if callable(value):
        return f"<function {value.__name__}>"
    try:
        json.dumps(value)
        return value
    except TypeError:
        return repr(value)


def record():
    """{command: {"help": text, "help_exit": code, "parsed": {dest: value}}} of today's CLI."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from vdnif_addon.cli import build_parser, main

    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = COLUMNS
    try:
        result = {}
        for name, argv in MINIMAL.items():
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                code = main([*argv[:1], "--help"])
            parsed = vars(build_parser().parse_args(argv))
            result[name] = {"help": out.getvalue(), "help_exit": code,
                            "parsed": {key: _value(value) for key, value in parsed.items()}}
        return result
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous


if __name__ == "__main__":
    import bpy  # noqa: F401  (the parser lists the demo scenes through the blender adapters)

    GOLDEN.write_text(json.dumps(record(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
