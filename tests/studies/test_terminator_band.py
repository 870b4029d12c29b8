"""tools/terminator_band.py: its --json is checked by the output rule before the model is
read: a foreign file is refused on one line and left as it was."""

import pathlib

from tool_errors import one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "terminator_band.py"
FOREIGN = b'{"mine": true}\n'


def test_a_foreign_json_file_is_refused_before_the_model_is_read(tmp_path):
    foreign = tmp_path / "band.json"
    foreign.write_bytes(FOREIGN)
    # a model that does not exist: only a check that comes first names the file
    line = one_error_line(TOOL, ["--model", tmp_path / "missing.vdnif", "--scene", "spot",
                                 "--secondary", "--json", foreign])
    assert "--json" in line and "refusing to replace it" in line
    assert foreign.read_bytes() == FOREIGN
    assert sorted(path.name for path in tmp_path.iterdir()) == ["band.json"]
