"""Every study tool checks the files it is told to write by the output rule before its work
starts: a file VDNIF did not write there is refused in one error line naming the option, and
is left as it was with nothing written beside it. Each case's other arguments would fail or
take long only after that check (a missing scene, model, dataset or level, absurd sizes), so
only a check that comes first gives the refusal. The tools whose output is a table of a run
folder (resolution_table, secondary_share, artist_rigs_study) are held in their own tests."""

import pathlib

import pytest
from tool_errors import refuses_foreign_output

TOOLS = pathlib.Path(__file__).resolve().parents[2] / "tools"

# tool, its arguments (FOREIGN: the foreign file's path, TMP: the test's folder), the option
# naming the foreign file, the foreign file's name
CASES = [
    ("corners_follow_choice", ["--json", "FOREIGN"], "--json", "choice.json"),
    ("surface_corners_study", ["--json", "FOREIGN"], "--json", "corners.json"),
    ("estimate_check", ["--scene", "no-such-scene", "--json", "FOREIGN"], "--json",
     "estimate.json"),
    ("bench_casts", ["--scene", "no-such-scene", "--json", "FOREIGN"], "--json", "casts.json"),
    ("terminator_band", ["--model", "TMP/missing.vdnif", "--scene", "spot", "--secondary",
                         "--json", "FOREIGN"], "--json", "band.json"),
    ("network_stages", ["--segments", "0", "--json", "FOREIGN"], "--json", "stages.json"),
    ("kernel_compile", ["--json", "FOREIGN"], "--json", "compile.json"),
    ("seed_spread_check", ["--before", "HEAD", "--now", "docs/results/no-such.json", "--json",
                           "FOREIGN"], "--json", "spread.json"),
    ("gpu_check", ["--benchmark", "FOREIGN"], "--benchmark", "benchmark.json"),
    ("time_to_clean", ["--data", "TMP/missing", "--scene", "arm", "--json", "FOREIGN",
                       "--model", "TMP/new.vdnif"], "--json", "x.json"),
    ("time_to_clean", ["--data", "TMP/missing", "--scene", "arm", "--json", "TMP/new.json",
                       "--model", "FOREIGN"], "--model", "x.vdnif"),
    ("dense_character", ["train", "--levels", "1", "2", "--out", "TMP"], "--out",
     "character-2.json"),
    ("dense_character", ["time", "--levels", "2", "--out", "TMP/missing", "--json", "FOREIGN",
                         "--markdown", "TMP/new.md"], "--json", "timings.json"),
    ("dense_character", ["time", "--levels", "2", "--out", "TMP/missing", "--json",
                         "TMP/new.json", "--markdown", "FOREIGN"], "--markdown", "timings.md"),
]


@pytest.mark.parametrize("tool, arguments, option, name", CASES,
                         ids=[f"{tool} {option}" for tool, _, option, _ in CASES])
def test_a_foreign_output_is_refused_before_the_work(tmp_path, tool, arguments, option, name):
    foreign = tmp_path / name
    filled = [str(foreign) if a == "FOREIGN" else a.replace("TMP", str(tmp_path))
              for a in arguments]
    line = refuses_foreign_output(TOOLS / f"{tool}.py", filled, foreign, option)
    assert name in line

