"""tools/threshold_sweep.py: the thresholds it sweeps, the development optimum it marks and
the rows of its table, and bad input ending in one error line."""

import pathlib

import pytest
from tool_errors import load_tool, one_error_line

from vdnif_addon.errors import VDNIFError
from vdnif_addon.settings import OCCLUSION_THRESHOLD
from vdnif_addon.training.validation import THRESHOLD_BINS, THRESHOLD_RANGE

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "threshold_sweep.py"
sweep = load_tool(TOOL)


def row(pose_set, occlusion, holes, extras):
    figures = {"false_negative_rate": holes, "false_positive_rate": extras}
    return {"pose_set": pose_set, "occlusion": occlusion, "vs_true": figures,
            "vs_embedded": figures}


def test_the_swept_thresholds_are_the_calibrations_grid_or_a_coarser_one():
    every = sweep.thresholds(0.02, *THRESHOLD_RANGE, THRESHOLD_BINS)
    # every threshold the calibration can choose: the multiples of 1/50 in 0.1..0.9
    assert every == [round(k / 50, 6) for k in range(5, 46)]
    assert THRESHOLD_BINS == 50 and len(every) == 41
    coarse = sweep.thresholds(0.04, *THRESHOLD_RANGE, THRESHOLD_BINS, extra=(0.14, 0.5))
    assert coarse[:4] == [0.1, 0.14, 0.18, 0.22] and coarse[-1] == 0.9
    assert 0.5 in coarse and len(coarse) == 21
    # a stored threshold off the grid is swept as well, in order
    assert sweep.thresholds(0.4, 0.1, 0.9, 50, extra=(0.33,)) == [0.1, 0.33, 0.5, 0.9]
    for bad in (0.03, 0.01, 0.0, -0.02):
        with pytest.raises(VDNIFError, match="not a positive multiple"):
            sweep.thresholds(bad, *THRESHOLD_RANGE, THRESHOLD_BINS)


def test_the_development_optimum_has_the_least_larger_of_holes_and_extras_ties_to_default():
    rows = [row("development", 0.3, 0.001, 0.006), row("development", 0.5, 0.002, 0.004),
            row("development", 0.7, 0.003, 0.002), row("development", 0.9, 0.0045, 0.0001),
            row("test", 0.3, 0.0, 0.0), row("test", 0.5, 0.0, 0.0),
            row("test", 0.7, 0.0024, 0.0035), row("test", 0.9, 0.0, 0.0)]
    summary = sweep.summarize(rows, OCCLUSION_THRESHOLD, 0.005)
    # the larger is least at 0.7 (0.3 %); the sum would choose 0.9 (0.46 % against 0.5 %)
    assert summary["occlusion"] == 0.7
    assert summary["test"]["vs_true"]["false_positive_rate"] == 0.0035   # its test figures
    assert summary["development_clean"] == [0.5, 0.7, 0.9]              # each rate <= 0.5 %
    # the test poses never choose: a better test row elsewhere does not move it
    rows[-1] = row("test", 0.9, 0.0, 0.0)
    assert sweep.summarize(rows, OCCLUSION_THRESHOLD, 0.005)["occlusion"] == 0.7
    # equal sums: the one nearest the default, as the calibration breaks ties
    tied = [row("development", t, 0.002, 0.002) for t in (0.3, 0.46, 0.56, 0.9)]
    assert sweep.best(tied, OCCLUSION_THRESHOLD)["occlusion"] == 0.46


def test_the_table_shows_the_default_the_stored_one_and_the_optimums_neighbours():
    grid = sweep.thresholds(0.02, *THRESHOLD_RANGE, THRESHOLD_BINS)
    rows = [row(s, t, abs(t - 0.76) / 100, 0.0001) for s in ("development", "test")
            for t in grid]
    data = {"rows": rows, "stored_thresholds": {"occlusion": 0.14, "candidate": 0.1},
            "default_threshold": 0.5}
    data["development_best"] = sweep.summarize(rows, OCCLUSION_THRESHOLD, 0.005)
    assert data["development_best"]["occlusion"] == 0.76
    assert sweep.table_thresholds(data) == [0.14, 0.5, 0.7, 0.72, 0.74, 0.76, 0.78, 0.8, 0.82]
    lines = sweep.table(data).splitlines()
    assert len(lines) == 2 + 9
    assert lines[2] == "| 0.14 (stored) | 0.62 % | 0.01 % | 0.62 % | 0.01 % |"
    assert lines[3].startswith("| 0.5 (default) | 0.26 % |")
    assert lines[7].startswith("| 0.76 (development optimum) | 0 % | 0.01 % |")
    # at the grid's end the neighbours stop there
    data["development_best"] = {"occlusion": 0.9}
    assert sweep.table_thresholds(data) == [0.14, 0.5, 0.84, 0.86, 0.88, 0.9]


@pytest.mark.parametrize("arguments, message", [
    (["run", "--model", "{tmp}/missing.vdnif", "--scene", "arm", "--json", "{tmp}/x.json"],
     "does not exist"),
    (["run", "--model", "{tmp}/missing.vdnif", "--scene", "arm", "--pose-set", "test",
      "--json", "{tmp}/x.json"], "--pose-set: the sweep chooses its poses"),
    (["run", "--model", "{tmp}/missing.vdnif", "--scene", "arm", "--also", "0.95", "--json",
      "{tmp}/x.json"], "--also 0.95 is outside the calibration's range 0.1..0.9"),
])
def test_bad_input_ends_in_one_error_line(tmp_path, arguments, message):
    line = one_error_line(TOOL, [a.format(tmp=tmp_path) for a in arguments])
    assert message in line


def test_the_json_is_checked_by_the_output_rule_before_any_work(tmp_path):
    model = tmp_path / "m.vdnif"
    model.write_bytes(b"not read before the output is checked")
    foreign = tmp_path / "notes.json"
    foreign.write_text('{"mine": true}\n')
    line = one_error_line(TOOL, ["run", "--model", str(model), "--scene", "arm", "--json",
                                 str(foreign)])
    assert "--json" in line and "refusing to replace it" in line
    assert foreign.read_text() == '{"mine": true}\n'
    line = one_error_line(TOOL, ["run", "--model", str(model), "--scene", "arm", "--json",
                                 str(model)])
    assert "is the model file this run reads" in line
    assert model.read_bytes() == b"not read before the output is checked"
