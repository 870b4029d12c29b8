"""The batch script as users run it: a subprocess with arguments after ``--``."""

import json
import subprocess
import sys

import pytest

from conftest import REPO

BATCH = REPO / "vdnif_addon" / "batch.py"


def run_batch(*args, timeout=120):
    result = subprocess.run([sys.executable, str(BATCH), "--", *map(str, args)],
                            capture_output=True, text=True, timeout=timeout, cwd=REPO)
    return result.returncode, result.stdout, result.stderr


def error_lines(stderr):
    return [line for line in stderr.splitlines() if line.startswith("vdnif: error:")]


def test_capture_writes_the_summary_json(tmp_path):
    target = tmp_path / "capture.json"
    code, out, err = run_batch("capture", "--scene", "arm", "--resolution", 16, "--poses", 4,
                               "--json", target)
    assert code == 0, err
    summary = json.loads(target.read_text())
    for key in ("grid_dims", "voxel_size", "occupied_voxels", "corners", "poses",
                "inverted_cells", "heads", "capture_s"):
        assert key in summary, key
    assert summary["poses"] == 4 and len(summary["inverted_cells"]) == 4
    assert summary["grid_dims"][2] == 18 and summary["voxel_size"] == pytest.approx(3 / 16)
    assert summary["occupied_voxels"] > 0 and summary["mode"] == "armature"
    assert "captured 'Arm'" in out and "ETA" in err


def test_static_mesh_file_is_reported_as_static(tmp_path):
    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    blend = tmp_path / "static.blend"
    script = (f"import bpy; bpy.ops.wm.read_homefile(use_empty=True); "
              f"bpy.ops.wm.obj_import(filepath={str(mesh)!r}); "
              f"cam = bpy.data.objects.new('Cam', bpy.data.cameras.new('Cam')); "
              f"bpy.context.scene.collection.objects.link(cam); "
              f"bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r})")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True)
    code, out, err = run_batch("capture", "--blend", blend, "--object", "tri",
                               "--resolution", 8, "--json", tmp_path / "s.json")
    assert code == 0, err
    assert "static" in out and "no deform modifier, one pose" in out
    assert json.loads((tmp_path / "s.json").read_text())["poses"] == 1
    code, out, err = run_batch("capture", "--blend", blend, "--object", "Cam")
    assert code == 1 and error_lines(err) == [
        "vdnif: error: object 'Cam' is a camera, not a mesh"], err


def test_dataset_then_references(tmp_path):
    out = tmp_path / "data"
    for pose_range in ("0:1", "1:3"):
        code, printed, err = run_batch("dataset", "--scene", "arm", "--resolution", 16,
                                       "--poses", 3, "--rays-per-pose", 128, "--out", out,
                                       "--pose-range", pose_range)
        assert code == 0, err
        assert "segments/s" in printed and "ETA" in err
    headers = sorted(out.glob("*.json"))
    assert [h.stem for h in headers] == ["shard-000000-000001", "shard-000001-000003"]
    header = json.loads(headers[1].read_text())
    assert header["pose_range"] == [1, 3] and len(header["poses"]) == 2
    assert header["counts"]["rays"] == 256 and header["counts"]["segments"] > 256
    report = tmp_path / "refs.json"
    code, printed, err = run_batch("references", "--scene", "arm", "--resolution", 16,
                                   "--poses", 2, "--width", 32, "--height", 24, "--json", report)
    assert code == 0, err
    data = json.loads(report.read_text())
    for key in ("distance_mae", "normal_error_deg", "hit_iou"):
        assert data["embedded_vs_true"][key] is not None
    assert data["rays_per_s"] > 0 and data["segments_per_s"] > 0
    assert data["width"] == 32 and data["height"] == 24 and len(data["per_pose"]) == 2
    summary = tmp_path / "train.json"
    code, printed, err = run_batch("train", "--data", out, "--variant", "lsnif", "--steps", 20,
                                   "--batch", 1024, "--log2-table-size", 12, "--json", summary)
    assert code == 0, err
    trained = json.loads(summary.read_text())
    assert trained["train"]["steps"] == 20 and trained["model_bytes"] > 0
    assert trained["network_config"]["pe_bands"] == 0
    assert trained["network_config"]["log2_table_size"] == 12
    assert (out / "lsnif.vdnif").is_file() and "ETA" in err


@pytest.mark.parametrize("args, message", [
    (["capture", "--scene", "arm", "--resolution", 300], "resolution 300 is outside 4..256"),
    (["capture", "--mesh", "nowhere.obj"], "mesh file 'nowhere.obj' does not exist"),
    (["capture", "--blend", "nowhere.blend"], "blend file 'nowhere.blend' does not exist"),
    (["capture", "--scene", "moon"], "invalid choice: 'moon'"),
    (["render"], "invalid choice: 'render'"),
    (["train", "--data", "nowhere"], "dataset folder 'nowhere' does not exist"),
    (["dataset", "--scene", "arm", "--poses", 4, "--out", "x", "--pose-range", "3:9"],
     "pose range 3:9 is outside 0:4"),
    (["dataset", "--scene", "arm", "--out", "x", "--rays-per-pose", 0],
     "rays per pose 0 must be at least 1"),
])
def test_failures_print_one_line_and_exit_non_zero(args, message):
    code, out, err = run_batch(*args)
    assert code != 0
    lines = error_lines(err)
    assert len(lines) == 1 and message in lines[0], err


def test_help_documents_every_command():
    code, out, _ = run_batch("--help")
    assert code == 0 and all(c in out for c in ("capture", "dataset", "references", "train",
                                             "bench-network"))
    code, out, _ = run_batch("capture", "--help")
    for option in ("--scene", "--mesh", "--rig", "--blend", "--object", "--resolution",
                   "--poses", "--seed", "--json"):
        assert option in out
