"""The batch commands behind ``batch.py``: the parser and ``main``; the commands are in
``pipeline`` and ``studies``, their shared options in ``options``.

Each command prints its summary to stdout, progress to stderr, and a failure as one line
``vdnif: error: ...`` with a non-zero exit code.

The installed extension ships without the studies (``vdnif_addon/studies/`` and
``cli/studies.py``, left out by ``blender_manifest.toml``): there the study commands are
listed as such and refuse to run with one line.
"""

import argparse
import contextlib
import os
import signal
import sys
import threading
import traceback
from importlib.util import find_spec

from ..errors import VDNIFError
from . import pipeline
from .options import add_declared_options, validate_arguments
from .outputs import run_inputs

# The studies' commands and the studies themselves; an import error inside them still raises.
if all(find_spec(f"{package}.studies") is not None
       for package in (__name__, __name__.rpartition(".")[0])):
    from . import studies
else:
    studies = None

STUDY_COMMANDS = ("demo", "experiment", "bench", "side-by-side", "bench-network")
"""The commands ``studies.add_commands`` adds: developer studies, not in the installed
extension."""
STUDY_MISSING = ("'{command}' is a developer study: it needs the repository checkout "
                 "(the installed extension leaves the studies out)")


class _DefaultsFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to every option that has a default its help does not state
    already; flags and options whose default is None (computed later) say it in words."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        # Identity, not equality: 0 == False, and a default of 0 is still shown.
        if (action.option_strings and all(default is not hidden for hidden in
                                          (None, False, argparse.SUPPRESS))
                and "default" not in text):
            text += f" (default: {show_default(default)})"
        return text


def show_default(value):
    """A default as --help shows it: 45.0 as 45, ["bunny", "million"] as bunny million."""
    if isinstance(value, (list, tuple)):
        return " ".join(map(show_default, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage mistake on one line, like every other failure, and shows
    every option's default in --help."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _DefaultsFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        raise _UsageError(f"{self.prog}: {message} (see --help)")


class _UsageError(VDNIFError):
    """A usage mistake on the command line; a VDNIFError, so that a script that parses a
    command's arguments (``tools/wrong_surface.py``) reports it as its other failures."""


def build_parser():
    parser = _Parser(prog="batch.py", description=(
        "VDNIF batch commands. Run as: blender --background --python vdnif_addon/batch.py "
        "-- <command> [options], or python vdnif_addon/batch.py -- <command> [options]."))
    parser.add_argument("--debug", action="store_true", help=(
        f"show the traceback of a failure (anywhere on the line; or {DEBUG_ENV}=1)"))
    commands = parser.add_subparsers(dest="command", metavar="<command>", parser_class=_Parser)
    pipeline.add_commands(commands)
    if studies is not None:
        studies.add_commands(commands)
    else:
        for name in STUDY_COMMANDS:
            commands.add_parser(name, help="developer study: needs the repository checkout")
    for name, command in commands.choices.items():
        if studies is not None or name not in STUDY_COMMANDS:
            add_declared_options(command, name)
    return parser


def _missing_study(argv):
    """The study command that ``argv`` names where the studies are not installed, else None
    (its parser is only a listing, and --help must fail the same way)."""
    command = next((arg for arg in argv if not arg.startswith("-")), None)
    return command if studies is None and command in STUDY_COMMANDS else None


DEBUG_ENV = "VDNIF_DEBUG"


def _debugging(argv):
    """(argv without ``--debug``, whether tracebacks are wanted: --debug or VDNIF_DEBUG=1)."""
    wanted = "--debug" in argv or os.environ.get(DEBUG_ENV, "") not in ("", "0")
    return [arg for arg in argv if arg != "--debug"], wanted


STOP_SIGNALS = ("SIGTERM", "SIGHUP")
"""Signals that end a batch run as Ctrl+C (SIGINT) does: every file being written is removed
(``safe_io.atomic_path``), the old ones stay. Windows has no SIGHUP."""


class Stopped(KeyboardInterrupt):
    """A stop signal, raised where the run is, so that its clean-ups run as for Ctrl+C."""


def _stop(number, frame):
    raise Stopped(signal.Signals(number).name)


@contextlib.contextmanager
def _stopping_cleanly():
    """Within the block, ``STOP_SIGNALS`` raise ``Stopped`` (only on the main thread, where
    Python runs signal handlers); the previous handlers come back after it."""
    saved = {}
    if threading.current_thread() is threading.main_thread():
        for name in STOP_SIGNALS:
            if hasattr(signal, name):
                saved[name] = signal.signal(getattr(signal, name), _stop)
    try:
        yield
    finally:
        for name, handler in saved.items():
            signal.signal(getattr(signal, name), handler)


def main(argv):
    """Runs one batch command; returns the process exit code: 0, or 1 after one line
    ``vdnif: error: ...`` on stderr for any failure (the traceback only with --debug)."""
    with _stopping_cleanly():
        return _main(argv)


def _main(argv):
    argv, debug = _debugging(list(argv))
    try:
        missing = _missing_study(argv)
        if missing is not None:
            raise VDNIFError(STUDY_MISSING.format(command=missing))
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 2
        validate_arguments(args)
        from ..output_rule import run_inputs as reading
        from ..threads import use_threads

        use_threads(getattr(args, "threads", None))
        with reading(run_inputs(args), getattr(args, "force", False)):
            return args.run(args)
    except VDNIFError as exc:           # usage mistakes (_UsageError) too
        if debug:
            traceback.print_exc()
        print(f"vdnif: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except Stopped as exc:
        print(f"vdnif: error: stopped by {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("vdnif: error: interrupted", file=sys.stderr)
        return 1
    except (Exception, SystemExit) as exc:     # noqa: BLE001 - the last line of defence
        if isinstance(exc, SystemExit) and exc.code in (0, None):
            return 0                           # --help, --version
        if debug:
            traceback.print_exc()
        where = "" if debug else f"; run again with --debug (or {DEBUG_ENV}=1) for the traceback"
        print(f"vdnif: error: internal error (a bug in VDNIF, please report it): "
              f"{type(exc).__name__}: {_one_line(exc)}{where}", file=sys.stderr)
        return 1


def _one_line(exc):
    from ..text import printable

    lines = str(exc).strip().splitlines()
    return printable(" ".join(line.strip() for line in lines)[:500] if lines
                     else type(exc).__name__)
