"""tools/calibration_curve.py: a trained model's holes and extras on its held-out poses'
calibration views, threshold by threshold, reproduce the threshold training stored; a
dataset made otherwise, or without views, ends in one error line."""

import json
import pathlib

import pytest
from batch_runner import run_batch
from tool_errors import load_tool, one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "calibration_curve.py"
tool = load_tool(TOOL)
SMALL = ("--scene", "arm", "--resolution", 16, "--poses", 10, "--rays-per-pose", 1024)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A small arm dataset with calibration views (32x32 at 1,024 rays per pose), a model
    trained on it briefly, and a dataset of the same scene with another seed."""
    folder = tmp_path_factory.mktemp("calibration")
    data, other, model = folder / "data", folder / "other", folder / "arm.vdnif"
    for out, seed in ((data, 0), (other, 1)):
        code, _, err = run_batch("dataset", *SMALL, "--seed", seed, "--out", out, timeout=300)
        assert code == 0, err
    code, _, err = run_batch("train", "--data", data, "--steps", 60, "--batch", 2048,
                             "--log2-table-size", 12, "--out", model, timeout=300)
    assert code == 0, err
    return data, other, model


def test_the_curve_reproduces_the_stored_threshold(trained, tmp_path):
    data, _, model = trained
    record = tool.curve(model, data)
    stored = record["stored_thresholds"]["occlusion"]
    assert record["larger_least"] == pytest.approx(stored)
    rows = record["rows"]
    assert [row["occlusion"] for row in rows] == pytest.approx([k / 50 for k in range(5, 46)])
    # the rule's choice is the least of the larger, read back from the rows themselves
    least = min(max(row["holes"], row["extras"]) for row in rows)
    chosen = next(row for row in rows if row["occlusion"] == pytest.approx(stored))
    assert max(chosen["holes"], chosen["extras"]) == pytest.approx(least)
    least_sum = min(row["holes"] + row["extras"] for row in rows)
    by_sum = next(row for row in rows if row["occlusion"] == pytest.approx(record["sum_least"]))
    assert by_sum["holes"] + by_sum["extras"] == pytest.approx(least_sum)
    # a higher threshold says hit less often: holes never fall, extras never rise
    holes = [row["holes"] for row in rows]
    extras = [row["extras"] for row in rows]
    assert holes == sorted(holes) and extras == sorted(extras, reverse=True)
    assert 0 < record["hit_rays"] <= record["rays_in_cells"]
    assert record["held_out_poses"]
    out = tmp_path / "curve.json"
    for _ in range(2):                  # the second run replaces the first's file
        tool.main(["--model", str(model), "--data", str(data), "--json", str(out)])
    written = json.loads(out.read_text())
    assert written["format"] == tool.FORMAT and written["provenance"]["network_hash"]
    [curve] = written["curves"]
    assert curve["larger_least"] == record["larger_least"]
    assert curve["rows"] == record["rows"]            # the same model and rows, exactly


def test_it_replaces_neither_a_file_it_did_not_write_nor_one_it_reads(trained, tmp_path):
    data, _, model = trained
    foreign = tmp_path / "notes.json"
    foreign.write_text('{"mine": true}')
    line = one_error_line(TOOL, ["--model", model, "--data", data, "--json", foreign])
    assert "--json" in line and str(foreign) in line
    assert foreign.read_text() == '{"mine": true}'
    before = model.read_bytes()
    line = one_error_line(TOOL, ["--model", model, "--data", data, "--json", model])
    assert "is the model file this run reads" in line and model.read_bytes() == before


def test_a_dataset_of_another_seed_ends_in_one_error_line(trained, tmp_path):
    _, other, model = trained
    line = one_error_line(TOOL, ["--model", model, "--data", other, "--json",
                                 tmp_path / "x.json"])
    assert "holds other poses than model" in line


def test_models_and_datasets_come_in_pairs(trained, tmp_path):
    data, other, model = trained
    line = one_error_line(TOOL, ["--model", model, "--data", data, "--data", other,
                                 "--json", tmp_path / "x.json"])
    assert "1 --model but 2 --data" in line


def test_a_missing_dataset_ends_in_one_error_line(trained, tmp_path):
    line = one_error_line(TOOL, ["--model", trained[2], "--data", tmp_path / "none",
                                 "--json", tmp_path / "x.json"])
    assert "does not exist" in line
