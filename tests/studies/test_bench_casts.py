"""tools/bench_casts.py: its --json is checked by the output rule before any scene is built
(a foreign file is refused on one line and left as it was), and a rerun replaces the
benchmark's own marked figures."""

import json
import pathlib
import subprocess
import sys

from tool_errors import one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "bench_casts.py"
FOREIGN = b'{"mine": true}\n'
SMALL = ["--resolution", "8", "--poses", "1", "--rays", "64", "--repeats", "1"]


def test_a_foreign_json_file_is_refused_before_any_work(tmp_path):
    foreign = tmp_path / "casts.json"
    foreign.write_bytes(FOREIGN)
    # a scene that does not exist: only a check that comes first names the file
    line = one_error_line(TOOL, ["--scene", "no-such-scene", "--json", foreign])
    assert "--json" in line and "refusing to replace it" in line
    assert foreign.read_bytes() == FOREIGN
    assert sorted(path.name for path in tmp_path.iterdir()) == ["casts.json"]


def test_a_rerun_replaces_its_own_figures(tmp_path):
    out = tmp_path / "casts.json"
    for _ in range(2):
        done = subprocess.run([sys.executable, str(TOOL), *SMALL, "--json", str(out)],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        record = json.loads(out.read_text())
        assert next(iter(record)) == "format" and record["format"] == "vdnif-bench-casts"
        assert record["poses"] == 1 and "provenance" in record
