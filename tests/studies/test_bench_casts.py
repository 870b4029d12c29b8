"""tools/bench_casts.py: a rerun replaces the benchmark's own marked figures (a foreign file
is refused: tests/studies/test_tools_output_rule.py)."""

import json
import pathlib
import subprocess
import sys

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "bench_casts.py"
SMALL = ["--resolution", "8", "--poses", "1", "--rays", "64", "--repeats", "1"]


def test_a_rerun_replaces_its_own_figures(tmp_path):
    out = tmp_path / "casts.json"
    for _ in range(2):
        done = subprocess.run([sys.executable, str(TOOL), *SMALL, "--json", str(out)],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        record = json.loads(out.read_text())
        assert next(iter(record)) == "format" and record["format"] == "vdnif-bench-casts"
        assert record["poses"] == 1 and "provenance" in record
