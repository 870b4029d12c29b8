"""The paper's experiments as commands that write their own section of the results file."""

import json

from test_batch import run_batch
from vdnif_addon.report import write_section


def test_a_section_is_replaced_in_place_and_others_are_kept(tmp_path):
    results = tmp_path / "results.md"
    for key, body in (("experiment static", "first"), ("experiment per-pose", "one"),
                      ("experiment static", "second")):
        write_section(results, key, key.title(), [body], "# Results\n")
    text = results.read_text()
    assert text.startswith("# Results\n\n<!-- experiment static -->\n## Experiment Static")
    assert text.count("<!-- experiment static -->") == 1 and "first" not in text
    assert text.index("second") < text.index("<!-- experiment per-pose -->") < text.index("one")


def test_per_pose_experiment_quick(tmp_path):
    results = tmp_path / "docs" / "results.md"
    code, printed, err = run_batch("experiment", "per-pose", "--quick", "--results", results,
                                   timeout=300)
    assert code == 0, err
    text = results.read_text()
    assert "## per-pose: One lsnif per unseen pose" in text
    assert "Command: `python vdnif_addon/batch.py -- experiment per-pose --quick`" in text
    record = json.loads((tmp_path / "docs" / "results" / "per-pose.json").read_text())
    runs = record["runs"]
    assert record["settings"]["eval_poses"] == 2 and set(runs) == {"arm/proposed",
                                                                   "arm/lsnif per pose"}
    for run in runs.values():
        assert {"vs_true", "vs_embedded", "model_bytes"} <= set(run)
        assert 0 <= run["vs_true"]["hit_iou"] <= 1
    # two per-pose models cost more bytes and training than the one proposed model
    assert runs["arm/lsnif per pose"]["model_bytes"] > runs["arm/proposed"]["model_bytes"]
    assert runs["arm/proposed"]["unseen_poses"] is True
    assert "arm/lsnif per pose: vs true" in printed
