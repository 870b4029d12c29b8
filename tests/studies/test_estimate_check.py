"""tools/estimate_check.py: its --json is checked by the output rule before the first scene
starts: a foreign file is refused on one line and left as it was."""

import pathlib

from tool_errors import one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "estimate_check.py"
FOREIGN = b'{"mine": true}\n'


def test_a_foreign_json_file_is_refused_before_any_scene(tmp_path):
    foreign = tmp_path / "estimate.json"
    foreign.write_bytes(FOREIGN)
    # a scene that does not exist: only a check that comes first names the file
    line = one_error_line(TOOL, ["--scene", "no-such-scene", "--json", foreign])
    assert "--json" in line and "refusing to replace it" in line
    assert foreign.read_bytes() == FOREIGN
    assert sorted(path.name for path in tmp_path.iterdir()) == ["estimate.json"]
