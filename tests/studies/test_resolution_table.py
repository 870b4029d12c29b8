"""tools/resolution_table.py: the output rule on its case files and its combined list,
checked before any work, and its table written only where --json names it."""

import json
import pathlib

from tool_errors import load_tool, one_error_line, refuses_foreign_output

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "resolution_table.py"
tool = load_tool(TOOL)


def case_row(case, holes=0.001, extras=0.002):
    table = [{"resolution": r, "embedding_error": 1e-4} for r in (32, 64, 128)]
    return {"format": tool.FORMAT, "case": case, "options": [],
            "suggestion": {"resolution": 64, "table": table, "knee": 32, "thin_floor": 64,
                           "met": True},
            "training": {"occlusion_threshold": 0.42},
            "test": {"false_negative_rate": holes, "false_positive_rate": extras},
            "clean": True}


def test_a_foreign_case_file_is_refused_before_the_case_starts(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    foreign = out / "arm.json"
    foreign.write_text('{"mine": true}\n')
    line = one_error_line(TOOL, ["run", "--case", "arm", "--out", str(out)])
    assert "--out" in line and "refusing to replace it" in line
    assert foreign.read_text() == '{"mine": true}\n'
    assert sorted(p.name for p in out.iterdir()) == ["arm.json"]      # nothing started


def test_the_table_writes_its_list_only_where_json_names_it(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    for case in ("plate", "arm"):
        (out / f"{case}.json").write_text(json.dumps(case_row(case)))
    text = tool.table(out)
    assert [line.split("|")[1].strip() for line in text.splitlines()[2:]] == ["arm", "plate"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]       # nothing beside it
    target = tmp_path / "all.json"
    tool.table(out, target)
    assert [row["case"] for row in json.loads(target.read_text())] == ["arm", "plate"]


def test_the_table_refuses_to_replace_a_foreign_file(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "arm.json").write_text(json.dumps(case_row("arm")))
    notes = tmp_path / "notes.json"
    refuses_foreign_output(TOOL, ["table", out, "--json", notes], notes, "--json")
    assert "is not a folder" in one_error_line(TOOL, ["table", tmp_path / "missing"])
