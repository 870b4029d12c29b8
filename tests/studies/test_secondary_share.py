"""tools/secondary_share.py: each run's commands, the runs collected from their folders (a run
without both evaluations left out) and their table, and a folder without runs or a run
that is not SCENE:SHARE ending in one error line."""

import json
import pathlib

import pytest
from tool_errors import load_tool, one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "secondary_share.py"


def figures(holes, ao):
    """An evaluation report's ``vs_true`` with the keys the tables read."""
    return {"vs_true": {"false_negative_rate": holes, "false_positive_rate": 2 * holes,
                        "distance_mae": 0.001, "normal_error_deg": 4.0, "ao_mae": ao,
                        "ao_mae_true_hit": ao / 2, "shadow_false_lit_rate": 0.02,
                        "shadow_false_lit_rate_true_hit": 0.002,
                        "shadow_false_shadow_rate": 0.01,
                        "shadow_false_shadow_rate_true_hit": 0.001, "shaded_psnr": 35.0}}


def write_run(folder, name, development, test=None):
    path = folder / name
    path.mkdir(parents=True)
    (path / "development.json").write_text(json.dumps(development))
    if test is not None:
        (path / "test.json").write_text(json.dumps(test))


def test_a_run_is_a_dataset_a_training_and_an_evaluation_per_pose_set(tmp_path):
    tool = load_tool(TOOL)
    dataset, train, *evaluations = tool.commands("spot", 0.1, tmp_path)
    assert dataset[:7] == ["dataset", "--scene", "spot", "--secondary-fraction", "0.1",
                           "--resolution", "recipe"]      # its table's, not a suggestion
    assert train[train.index("--data") + 1] == dataset[dataset.index("--out") + 1]
    model = train[train.index("--out") + 1]
    assert [(e[e.index("--model") + 1], e[e.index("--pose-set") + 1], "--secondary" in e)
            for e in evaluations] == [(model, "development", True), (model, "test", True)]
    assert tool.run_folder(tmp_path, "spot", 0.1) == tmp_path / "spot-0.1"


def test_the_tables_hold_every_finished_run_in_share_order(tmp_path):
    tool = load_tool(TOOL)
    write_run(tmp_path, "spot-0.1", figures(0.002, 0.004), figures(0.003, 0.005))
    write_run(tmp_path, "spot-0.0", figures(0.001, 0.008), figures(0.0015, 0.009))
    write_run(tmp_path, "bunny-0.2", figures(0.004, 0.02))          # no test report yet
    out = tmp_path / "secondary.json"
    text = tool.table(tmp_path, out)
    rows = [line.split(" | ")[:3] for line in text.splitlines() if line.startswith("| spot")]
    assert rows == [["| spot", "0", "development"], ["| spot", "0", "test"],
                    ["| spot", "0.1", "development"], ["| spot", "0.1", "test"]]
    assert "| spot | 0 | development | 0.1 % / 0.2 % |" in text
    assert "| spot | 0 | test | 0.15 % / 0.3 % |" in text
    assert "| 4.00 | 0.008 / 0.004 |" in text and "0.009 / 0.0045" in text
    assert text.splitlines()[-1].endswith("| 35.00 |")
    record = json.loads(out.read_text())
    assert list(record["runs"]) == ["spot/0.0", "spot/0.1"]
    assert record["runs"]["spot/0.1"]["secondary_fraction"] == 0.1
    assert "commit" in json.dumps(record["provenance"])
    assert tool.table(tmp_path, out) == text            # its own file, replaced


def test_the_table_writes_only_where_json_names_it_and_never_over_a_foreign_file(tmp_path):
    tool = load_tool(TOOL)
    runs = tmp_path / "runs"
    write_run(runs, "spot-0.0", figures(0.001, 0.008), figures(0.0015, 0.009))
    tool.table(runs)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    notes = tmp_path / "notes.json"
    notes.write_text('{"mine": true}\n')
    line = one_error_line(TOOL, ["table", runs, "--json", notes])
    assert "--json" in line and "refusing to replace it" in line
    assert notes.read_text() == '{"mine": true}\n'


def test_a_folder_without_finished_runs_ends_in_one_error_line(tmp_path):
    write_run(tmp_path, "bunny-0.0", figures(0.001, 0.01))
    line = one_error_line(TOOL, ["table", tmp_path])
    assert "no run with both evaluations" in line and str(tmp_path) in line


@pytest.mark.parametrize("run", ["bunny", "bunny:x", ":0.1", "bunny:1.5"])
def test_a_run_that_is_not_a_scene_and_share_is_refused(run, tmp_path):
    line = one_error_line(TOOL, ["run", "--out", tmp_path, "--run", run])
    assert run in line
    assert list(tmp_path.iterdir()) == []
