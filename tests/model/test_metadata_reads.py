"""Model metadata is read through ``ModelMetadata``'s attributes, checked once by
``ModelMetadata.from_dict``: no module reads it by string key (``extra["grid"]``,
``metadata["train_info"]``, ``extra.get("object")``), which would bypass the checks. Only
``vdnif_addon/model/metadata.py`` reads the stored plain data."""

import pathlib
import re

from source_scan import matching_lines

REPO = pathlib.Path(__file__).resolve().parents[2]
ALLOWED = pathlib.Path("vdnif_addon/model/metadata.py")
KEY = r"""\s*["']"""
STRING_KEY_READ = re.compile(
    rf"""\b(extra|metadata|meta|train_info)\s*(\[{KEY}|\.get\({KEY})"""
    rf"""|\[{KEY}(extra|train_info)["']\s*\]""")
"""A string-key read of model metadata: a key in brackets or ``.get`` on a name that held
the metadata dict, or its old ``extra`` / ``train_info`` entries by name."""


def string_key_reads(repo):
    """``path:line: text`` of each string-key read of model metadata in ``repo``'s root
    modules and its vdnif_addon, operators, panels and tools folders, but for ALLOWED."""
    return matching_lines(repo, STRING_KEY_READ, ALLOWED.as_posix())


def test_no_module_reads_model_metadata_by_string_key():
    assert string_key_reads(REPO) == []


def test_a_planted_string_key_read_is_found(tmp_path):
    """The scan finds each form of read where it may hide, and leaves the allowed module,
    non-string keys and other names alone."""
    planted = {
        "vdnif_addon/posed/render.py": 'table = model.metadata["extra"]["albedo_table"]',
        "vdnif_addon/cli/pipeline.py": 'resolution = extra["grid"]["resolution"]',
        "operators/passes.py": "trained = extra.get('train_poses', [])",
        "panels/sidebar.py": 'steps = metadata["train_info"]["steps"]',
        "tools/albedo_ceiling.py": 'config = meta.get("network_config")',
        "storage.py": 'info = load_model(path)[1]["train_info"]',
    }
    harmless = {
        ALLOWED.as_posix(): 'version = data["version"]',
        "vdnif_addon/blender/extremes.py": "bone.matrix_basis @= extra[bone.name]",
        "vdnif_addon/progress.py": 'line = f"{done}{extra}"',
    }
    for files in (planted, harmless):
        for name, text in files.items():
            path = tmp_path / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(f"def f(model, extra, meta, metadata, data, bone, done):\n"
                            f"    {text}\n")
    found = string_key_reads(tmp_path)
    assert sorted(entry.split(":")[0] for entry in found) == sorted(planted)
    assert all(entry.endswith(planted[entry.split(":")[0]]) for entry in found)


def test_the_rest_pose_needs_no_frame_and_every_other_pose_does():
    """A static variant trains on the rest pose (``poses.REST_POSE``), which has no frame; any
    other pose must carry a finite one."""
    from vdnif_addon.model.metadata import poses_problem

    assert poses_problem([{"rest": True}], "poses are") is None
    assert poses_problem([{"frame": 3.0, "bones": {}}], "poses are") is None
    for bad in ([{"rest": False}], [{"rest": 1}], [{}], [{"frame": "3"}]):
        assert "pose 0 has no finite frame number" in poses_problem(bad, "poses are")
