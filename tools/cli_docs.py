"""Writes the option tables of docs/cli.md from the batch parser, whose setting options are
generated from the settings' declarations (``vdnif_addon/declarations.py``): one row per
option of each command, its default and its --help text. The prose around the tables is
the doc's own; only the rows under each ``| option | default | what |`` header are written.

    python tools/cli_docs.py --check    # exit 1 when docs/cli.md differs from the parser
    python tools/cli_docs.py --write    # rewrite its tables

Rules: a row gives the long option with its metavar (or its choices, ``a|b``), ``...`` after
an option that takes several values; the default is the parser's (``off`` for a flag,
``required`` for a required option), or where that is computed later (None) the words of
the help's closing ``(default: ...)`` or of its option group's title, else ``none``; the
what is the help without that closing default.
"""

import argparse
import pathlib
import re
import sys

REPO = pathlib.Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "cli.md"
HEADER = "| option | default | what |"
EVERY_COMMAND = "Every command"
"""The heading of the top-level options' table."""
_DEFAULT = re.compile(r"\s*\(default:? ((?:[^()]|\([^()]*\))*)\)$")
"""A help's closing ``(default: words)``, one level of parentheses inside the words."""


def _parser():
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from vdnif_addon.cli import build_parser

    return build_parser()


def parsers(parser=None):
    """{table heading: parser}: the top level's and every command's."""
    parser = parser or _parser()
    commands = next(action for action in parser._actions
                    if isinstance(action, argparse._SubParsersAction))
    return {EVERY_COMMAND: parser, **commands.choices}


def _cell(text):
    return str(text).replace("|", "\\|")


def _code(text):
    """Words with ``<placeholders>`` in backticks, which markdown would read as tags."""
    return re.sub(r"(\S*<[^>\s]+>\S*?)([,;)]?(?:\s|$))", r"`\1`\2", text)


def row(action, group=""):
    """(key, the table row) of one argparse action of the option group titled ``group``."""
    from vdnif_addon.cli import show_default

    help_text = action.help or ""
    closing = _DEFAULT.search(help_text) or _DEFAULT.search(group or "")
    what = _DEFAULT.sub("", help_text)
    several = action.nargs in ("+", "*")
    if not action.option_strings:
        key = spec = "|".join(action.choices)
    else:
        key = max(action.option_strings, key=len)
        if action.nargs == 0:
            spec = key
        else:
            word = action.metavar or (
                "|".join(action.choices) if action.choices and not several
                else action.dest.upper())
            spec = f"{key} {word}" + (" ..." if several else "")
        if several and action.choices:
            what += ": " + "|".join(action.choices)
    if action.required or (not action.option_strings and action.default is None):
        default = "required"
    elif isinstance(action, argparse._StoreTrueAction):
        default = "off"
    elif action.default is not None:
        default = show_default(action.default)
    else:
        default = closing.group(1) if closing else "none"
    return key, f"| `{_cell(spec)}` | {_cell(_code(default))} | {_cell(_code(what))} |"


def tables(parser=None):
    """{heading: [row, ...]} of every command's options in the parser's order."""
    generated = {}
    for heading, command in parsers(parser).items():
        groups = {id(action): group.title for group in command._action_groups
                  for action in group._group_actions}
        generated[heading] = [row(action, groups[id(action)])[1] for action in command._actions
                              if not isinstance(action, (argparse._HelpAction,
                                                         argparse._SubParsersAction))]
    return generated


def rewrite(text, generated):
    """``text`` with the rows of each option table replaced by ``generated[heading]``."""
    lines, out, heading, fenced, skipping = text.splitlines(), [], None, False, False
    for line in lines:
        if skipping and line.startswith("|"):
            continue
        skipping = False
        out.append(line)
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            heading = line.lstrip("#").strip()
        elif not fenced and line == HEADER:
            if heading not in generated:
                raise SystemExit(f"docs/cli.md: an option table under '{heading}', which is "
                                 "no command")
            out += ["| --- | --- | --- |", *generated[heading]]
            skipping = True
    return "\n".join(out) + "\n"


def main(argv):
    parser = argparse.ArgumentParser(description="Check or write docs/cli.md's option tables.")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="exit 1 when the doc differs")
    mode.add_argument("--write", action="store_true", help="rewrite the doc's tables")
    args = parser.parse_args(argv)
    text = DOC.read_text()
    expected = rewrite(text, tables())
    if args.write:
        DOC.write_text(expected)
        print(f"wrote {DOC.relative_to(REPO)}")
        return 0
    if expected != text:
        print("docs/cli.md's option tables differ from the parser: run "
              "python tools/cli_docs.py --write", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
