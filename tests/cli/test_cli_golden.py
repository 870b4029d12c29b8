"""The batch CLI behaves as it did before it moved out of ``vdnif_addon/commands.py``: every
command's --help text, exit code and parsed defaults equal ``golden/cli.json``, recorded from
the old parser (``golden/make_cli_golden.py``)."""

import importlib.util
import json
import pathlib

import pytest

HERE = pathlib.Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("make_cli_golden",
                                               HERE / "golden" / "make_cli_golden.py")
make_cli_golden = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_cli_golden)

GOLDEN = json.loads(make_cli_golden.GOLDEN.read_text())


@pytest.fixture(scope="module")
def recorded():
    import bpy  # noqa: F401  (before the parser's blender adapters)

    return make_cli_golden.record()


def test_every_command_is_in_the_golden(recorded):
    assert sorted(recorded) == sorted(GOLDEN) and len(GOLDEN) == 12


@pytest.mark.parametrize("command", sorted(GOLDEN))
def test_help_and_defaults_equal_the_golden(recorded, command):
    now, then = recorded[command], GOLDEN[command]
    assert now["help_exit"] == then["help_exit"] == 0
    assert now["help"] == then["help"]
    assert now["parsed"] == then["parsed"]
