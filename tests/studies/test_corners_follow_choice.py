"""tools/corners_follow_choice.py: its --json is checked by the output rule before any scene
is built: a foreign file is refused on one line and left as it was."""

import pathlib

from tool_errors import one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "corners_follow_choice.py"
FOREIGN = b'{"mine": true}\n'


def test_a_foreign_json_file_is_refused_before_any_scene(tmp_path):
    foreign = tmp_path / "choice.json"
    foreign.write_bytes(FOREIGN)
    line = one_error_line(TOOL, ["--json", foreign])
    assert "--json" in line and "refusing to replace it" in line
    assert foreign.read_bytes() == FOREIGN
    assert sorted(path.name for path in tmp_path.iterdir()) == ["choice.json"]
