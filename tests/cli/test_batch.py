"""The batch script as users run it: a subprocess with arguments after ``--``."""

import json
import math
import os
import re
import struct
import subprocess
import sys

import pytest
from batch_runner import error_lines, run_batch
from conftest import REPO

from vdnif_addon.inference.metrics import SPEED_MIN_HIT_IOU, speed_withheld
from vdnif_addon.model.model_file import load_model
from vdnif_addon.output_rule import OUTPUT_MARK


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


def test_runs_leave_no_blender_session_folder(tmp_path):
    """Blender makes a session folder (blender_XXXXXX) in the temporary folder; a batch run
    deletes it when it ends, after a success and after an error alike."""
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    env = dict(os.environ, TMPDIR=str(temporary))
    code, _, err = run_batch("capture", "--scene", "arm", "--resolution", 8, "--poses", 2,
                             env=env)
    assert code == 0, err
    code, _, err = run_batch("capture", "--scene", "arm", "--resolution", 3, env=env)
    assert code == 1 and len(error_lines(err)) == 1, err
    assert list(temporary.iterdir()) == []


@pytest.mark.slow
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


@pytest.mark.slow
def test_dataset_then_references(tmp_path):
    out = tmp_path / "data"
    for pose_range in ("0:1", "1:3"):
        code, printed, err = run_batch("dataset", "--scene", "arm", "--resolution", 16,
                                       "--poses", 3, "--rays-per-pose", 128, "--out", out,
                                       "--pose-range", pose_range)
        assert code == 0, err
        assert "segments/s" in printed and "ETA" in err
        # the size it expected (stderr, before the walk) and the size it wrote
        start, stop = map(int, pose_range.split(":"))
        shard = out / f"shard-{start:06d}-{stop:06d}"
        written = sum(shard.with_suffix(suffix).stat().st_size for suffix in (".npz", ".json"))
        found = re.search(r"on disk \S+ \S+ \(([\d,]+) bytes; estimated (\S+ \S+)\)", printed)
        assert found and int(found[1].replace(",", "")) == written, printed
        assert f"dataset about {found[2]} on disk" in err.split("ETA")[0]
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
    # the history: per progress record the step, the positive task losses and validation
    history = trained["history"]
    assert history[-1]["step"] == 20 and all(set(r) == {"step", "losses", "validation"}
                                             for r in history)
    assert all(loss > 0 for r in history for loss in r["losses"].values())
    assert trained["plot"] == str(out / "lsnif-training.png")
    assert (out / "lsnif-training.png").is_file()


@pytest.mark.parametrize("args, message", [
    (["capture", "--scene", "arm", "--resolution", 300], "resolution 300 is outside 4..256"),
    (["capture", "--mesh", "nowhere.obj"], "mesh file 'nowhere.obj' does not exist"),
    (["capture", "--blend", "nowhere.blend"], "blend file 'nowhere.blend' does not exist"),
    (["capture", "--scene", "moon"], "invalid choice: 'moon'"),
    (["render", "--out", "x"], "the following arguments are required: --model"),
    (["train"], "give --data DIR (a dataset folder) or scene options"),
    (["capture", "--scene", "arm", "--deform", "wobble:3"], "unknown deform kind 'wobble'"),
    (["references", "--scene", "arm", "--scale", "-2"], "object scale -2 must be a finite"),
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
                                             "render", "evaluate", "demo", "bench-network"))
    code, out, _ = run_batch("capture", "--help")
    for option in ("--scene", "--mesh", "--rig", "--blend", "--object", "--resolution",
                   "--poses", "--seed", "--json"):
        assert option in out


# Runs every command's --help and refused command lines through ``cli.main`` as
# ``batch.py`` calls it, and prints, per command line, its exit code and which of the heavy
# modules it left imported.
PARSE_ONLY = """
import argparse, contextlib, io, json, sys
from vdnif_addon.cli import build_parser, main
HEAVY = ("bpy", "torch", "warp")
commands = next(a for a in build_parser()._actions
                if isinstance(a, argparse._SubParsersAction)).choices
lines = [["--help"], *([name, flag] for name in commands
                       for flag in ("--help", "--no-such-option"))] + [
    line.split() for line in sys.argv[1:]]
report = []
for argv in lines:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(argv)
    report.append([argv, code, err.getvalue(), [m for m in HEAVY if m in sys.modules]])
print(json.dumps(report))
"""


def test_help_and_refused_command_lines_import_neither_bpy_torch_nor_warp():
    """The parser and the checks that run before any work import no heavy module: a refused
    command line or --help of every command answers at once under plain ``python``."""
    refused = ["capture --seed -1", "capture --scale 0", "capture --deform bend:inf",
               "render --model m.vdnif --frames x", "demo --scene moon",
               "dataset --out d --rays-per-pose 0", "train --data d --growth 99", "train",
               "capture --mesh nowhere.obj", "dataset --blend nowhere.blend --out d",
               "train --mesh . --out m.vdnif", "render --model nowhere.vdnif --out r",
               "evaluate --model ."]
    result = subprocess.run([sys.executable, "-c", PARSE_ONLY, *refused], cwd=REPO,
                            capture_output=True, text=True, timeout=120, check=True)
    report = json.loads(result.stdout)
    commands = {argv[0] for argv, *_ in report}
    assert {"capture", "dataset", "references", "train", "render", "evaluate", "demo",
            "bench-network", "side-by-side"} <= commands
    for argv, code, err, heavy in report:
        refusal = argv[-1] != "--help"
        assert code == (1 if refusal else 0), (argv, err)
        assert len(error_lines(err)) == refusal, (argv, err)
        assert heavy == [], (argv, heavy)


def test_help_states_every_default_it_has():
    """Every option with a default shows it in --help, and help text that names a default
    by hand names the one argparse will use."""
    import argparse

    from vdnif_addon.cli import build_parser, show_default

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    checked = 0
    for name, command in commands.choices.items():
        formatter = command._get_formatter()
        for action in command._actions:
            if not action.option_strings or action.default in (None, False, argparse.SUPPRESS):
                continue
            shown = formatter._expand_help(action)
            assert "default" in shown and show_default(action.default) in shown, (
                name, action.dest, shown)
            checked += 1
    assert checked > 40


@pytest.fixture(scope="module")
def quick_demo(tmp_path_factory):
    """``demo --quick`` run once: its folder and its JSON."""
    out = tmp_path_factory.mktemp("demo")
    code, printed, err = run_batch("demo", "--quick", "--scene", "arm", "--out", out,
                                   "--json", out / "d.json", timeout=300)
    assert code == 0, err
    assert "vs true: distance MAE" in printed and "ETA" in err
    return out, json.loads((out / "d.json").read_text())


@pytest.mark.slow
def test_demo_quick_runs_the_main_job_end_to_end(quick_demo):
    out, report = quick_demo
    assert report == json.loads((out / "report.json").read_text())
    assert report["variant"] == "proposed" and report["unseen_poses"] is True
    assert report["config"]["network"]["pe_bands"] == 3
    assert report["config"]["train"]["steps"] == 600
    for reference in ("vs_true", "vs_embedded"):
        metrics = report[reference]
        # rates over the reference's hits: IoU = TP / (TP + FN + FP) = (1 - FNR) / (1 + FPR)
        assert metrics["hit_iou"] == pytest.approx(
            (1 - metrics["false_negative_rate"]) / (1 + metrics["false_positive_rate"]))
        # h = longest rest side / R (DESIGN section 2): R voxels to one object unit
        assert metrics["distance_mae_voxels"] == pytest.approx(
            metrics["distance_mae"] * report["resolution"])
        assert "albedo_psnr" not in metrics                # one constant albedo: nothing
        assert "material_accuracy" not in metrics          # one material: no metric
    timings = report["timings"]
    for key in ("train_s", "train_samples_per_s", "prepare_pose_s"):
        assert timings[key] > 0, key
    iou = report["vs_true"]["hit_iou"]
    if iou >= SPEED_MIN_HIT_IOU:
        assert timings["render_rays_per_s"] > 0 and report["speed_withheld"] is None
    else:                                                   # no speed from a model that misses
        assert timings["render_rays_per_s"] is None
        assert report["speed_withheld"] == speed_withheld(iou)
        assert f"n/a ({speed_withheld(iou)})" in (out / "report.md").read_text()
    assert report["model_bytes"] == (out / "arm-proposed.vdnif").stat().st_size
    # the thresholds the model calibrated, which set its trade of holes for extras
    assert report["thresholds"] == load_model(out / "arm-proposed.vdnif")[1].thresholds.to_dict()
    # a regression loss below 0.5 lowers its s
    # below where the recipe starts it (log 0.5, every task at weight 1)
    weights = report["log_variances"]
    assert set(weights) == {"occlusion", "distance", "normal"}
    assert weights["distance"] < math.log(0.5) and weights["normal"] < math.log(0.5), weights
    assert len(report["per_pose"]) == report["poses"] == 2
    assert "![reference, predicted, error per pass](figure-vs-true.png)" in (
        out / "report.md").read_text()
    assert sorted(path.name for path in (out / "passes").iterdir()) == sorted(
        [f"{name}.png" for name in ("hit", "distance", "normal", "albedo", "material", "ao",
                                    "shadow", "shaded")] + ["passes.exr"])
    from blender_exr import pass_names

    assert pass_names(out / "passes" / "passes.exr") == {
        "Combined", "Depth", "Normal", "DiffCol", "IndexMA", "AO", "Shadow", "Shaded"}
    assert "The shaded image" in (out / "report.md").read_text()
    assert timings["exact_rays_per_s"] > 0 and timings["exact_prepare_s"] > 0
    markdown = (out / "report.md").read_text()
    assert "Verdict against the mesh on the 2 unseen poses" in markdown
    assert "Goal" not in markdown and "![speed and accuracy](speed-accuracy.png)" in markdown
    assert report["figures"]["speed_accuracy"] == str(out / "speed-accuracy.png")
    assert report["training_plot"] == str(out / "training.png")
    assert "![training loss per task](training.png)" in (out / "report.md").read_text()
    # the AO and shadow rows, from the network's own hits and from the true ones, and figure
    for reference in ("vs_true", "vs_embedded"):
        for key in ("ao_mae", "shadow_false_lit_rate", "shadow_false_shadow_rate"):
            for suffix in ("", "_true_hit"):
                number = report[reference][f"{key}{suffix}"]
                assert number is not None and 0 <= number <= 1, (reference, key, suffix)
    markdown = (out / "report.md").read_text()
    rows = [line for line in markdown.splitlines() if line.startswith(("| true |",
                                                                       "| embedded |"))]
    assert len(rows) == 2 and all("n/a" not in row and row.count("%") == 4 for row in rows)
    assert "![AO and shadow: reference, predicted, error](figure-secondary-vs-true.png)" in (
        markdown)
    assert report["figures"]["figure_secondary_vs_true"] == str(
        out / "figure-secondary-vs-true.png")
    for name in ("figure-secondary-vs-true.png", "figure-vs-true.png", "speed-accuracy.png"):
        header = (out / name).read_bytes()[16:24]                       # PNG's IHDR
        width, height = struct.unpack(">II", header)
        assert width > 500 and height > 300, name       # a titled figure, not the images
    assert report["secondary"]["network_offset"] > report["secondary"]["offset"]


@pytest.mark.slow
def test_render_and_evaluate_with_the_demo_model(quick_demo, tmp_path):
    out, demo_report = quick_demo
    model = out / "arm-proposed.vdnif"
    code, printed, err = run_batch("render", "--model", model, "--scene", "arm", "--frame", 30,
                                   "--width", 24, "--height", 16, "--references",
                                   "--out", tmp_path / "r")
    assert code == 0, err
    summary = json.loads((tmp_path / "r" / "render.json").read_text())
    assert summary["hit_pixels"] > 0 and summary["frame"] == 30
    assert "orbit viewpoint" in summary["view"]
    for prefix in ("", "true-", "embedded-"):
        assert (tmp_path / "r" / f"{prefix}passes.exr").is_file()
        assert (tmp_path / "r" / f"{prefix}distance.png").is_file()
    code, printed, err = run_batch("evaluate", "--model", model, "--scene", "arm", "--poses", 2,
                                   "--width", 32, "--height", 24, "--json", tmp_path / "e.json",
                                   "--out", tmp_path / "e", "--secondary")
    assert code == 0, err
    report = json.loads((tmp_path / "e.json").read_text())
    # the demo evaluated the same unseen poses with the same cameras, AO and shadow rays
    assert report["vs_true"] == demo_report["vs_true"]
    assert (tmp_path / "e" / "figure-vs-embedded.png").is_file()


@pytest.mark.slow
def test_wrong_surface_tool_evaluates_as_evaluate_does(quick_demo, tmp_path):
    """tools/wrong_surface.py takes evaluate's options and evaluates the same poses and
    pixels: its figure over every both-hit pixel is evaluate's own."""
    out, _ = quick_demo
    model = out / "arm-proposed.vdnif"
    options = ("--model", model, "--scene", "arm", "--poses", 2, "--width", 32, "--height", 24)
    code, _, err = run_batch("evaluate", *options, "--json", tmp_path / "e.json")
    assert code == 0, err
    report = json.loads((tmp_path / "e.json").read_text())
    done = subprocess.run([sys.executable, str(REPO / "tools" / "wrong_surface.py"),
                           *map(str, options)], capture_output=True, text=True, timeout=120,
                          cwd=REPO)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    heads = [line.split(":")[0] for line in lines if not line.startswith(" ")]
    assert heads == ["predicted vs true", "predicted vs embedded", "embedded vs true"]
    figure = next(line for line in lines if line.startswith("  distance_mae:"))
    assert float(figure.split()[1]) == pytest.approx(report["vs_true"]["distance_mae"],
                                                     rel=1e-3)


@pytest.mark.slow
def test_secondary_speed_tool_times_a_captured_pose_without_blender(quick_demo, tmp_path):
    """tools/secondary_speed.py: ``capture`` writes a pose with Blender, ``time`` times the
    network's and Warp's secondary rays from it in a process that never imports bpy; each
    path casts its hits times the samples and at most a shadow ray per hit."""
    out, _ = quick_demo
    model, pose = out / "arm-proposed.vdnif", tmp_path / "pose.npz"
    tool = [sys.executable, str(REPO / "tools" / "secondary_speed.py")]
    done = subprocess.run([*tool, "capture", str(pose), "--", "--model", str(model),
                           "--scene", "arm", "--width", "32", "--height", "24"],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 0, done.stderr
    guard = "import sys; sys.modules['bpy'] = None; sys.argv = sys.argv[1:]; "
    done = subprocess.run([sys.executable, "-c", guard + "import runpy; runpy.run_path("
                           "sys.argv[0], run_name='__main__')", str(REPO / "tools" /
                           "secondary_speed.py"), "time", str(pose), "--model", str(model),
                           "--device", "cpu", "--repeats", "1", "--samples", "2"],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 0, done.stderr
    import torch

    from vdnif_addon.kernels.runtime import bfloat16_native

    auto = "bfloat16" if bfloat16_native(torch.device("cpu")) else "float32"
    assert f"the MLPs in {auto};" in done.stdout.splitlines()[0]
    for path in ("network", "Warp refit"):
        line = next(line for line in done.stdout.splitlines()
                    if line.startswith(f"{path}, 2 AO sample(s)"))
        rays = int(line.split("secondary ")[1].split(" rays")[0].replace(",", ""))
        hits = int(line.split("; ")[-1].split(" hits")[0].replace(",", ""))
        assert hits > 50 and 2 * hits <= rays <= 3 * hits, line
    done = subprocess.run([*tool, "time", str(REPO / "README.md"), "--model", str(model)],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 1 and len(done.stderr.strip().splitlines()) == 1
    assert "README.md is not a readable pose file" in done.stderr


COUNT_MODEL_READS = """
import sys
from vdnif_addon.model import model_file
reads = []
read = model_file.load_model
model_file.load_model = lambda *a, **k: reads.append(a) or read(*a, **k)
from vdnif_addon.cli import main
code = main(sys.argv[1:])
print("model reads:", len(reads))
sys.exit(code)
"""


@pytest.mark.slow
@pytest.mark.parametrize("command", [
    ("render", "--frame", 30, "--width", 8, "--height", 8),
    ("evaluate", "--poses", 1, "--width", 8, "--height", 8)])
def test_render_and_evaluate_read_the_model_file_once(quick_demo, tmp_path, command):
    out, _ = quick_demo
    args = [*command, "--model", out / "arm-proposed.vdnif", "--scene", "arm",
            "--out", tmp_path / "o"]
    result = subprocess.run([sys.executable, "-c", COUNT_MODEL_READS, *map(str, args)],
                            capture_output=True, text=True, timeout=120, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "model reads: 1" in result.stdout.splitlines()


@pytest.mark.slow
def test_bad_models_and_cameras_fail_on_one_line_and_overwrite_nothing(quick_demo, tmp_path):
    out, _ = quick_demo
    model = out / "arm-proposed.vdnif"
    target = tmp_path / "r"
    target.mkdir()
    (target / "normal.png").write_bytes(b"keep")
    (target / OUTPUT_MARK).write_text("")      # a render folder of VDNIF's, from an older run
    future = tmp_path / "future.vdnif"
    import torch
    archive = torch.load(model, weights_only=True)
    torch.save(dict(archive, version=99), future)
    cases = [
        (["--model", model, "--scene", "lattice"], "was trained on 'Arm' at resolution 16"),
        (["--model", model, "--scene", "arm", "--resolution", 32],
         "not on 'Arm' at resolution 32"),
        (["--model", model, "--scene", "arm", "--camera", "Ghost"], "no camera named 'Ghost'"),
        (["--model", future, "--scene", "arm"], "format version 99, newer than this add-on"),
        (["--model", tmp_path / "none.vdnif", "--scene", "arm"], "does not exist"),
    ]
    for args, message in cases:
        code, _, err = run_batch("render", *args, "--out", target)
        lines = error_lines(err)
        assert code == 1 and len(lines) == 1 and message in lines[0], err
    assert sorted(p.name for p in target.iterdir()) == ["normal.png", OUTPUT_MARK]
    assert (target / "normal.png").read_bytes() == b"keep"


@pytest.mark.slow
def test_train_from_scene_options_generates_its_dataset(tmp_path):
    data, model = tmp_path / "data", tmp_path / "m.vdnif"
    code, printed, err = run_batch("train", "--scene", "arm", "--resolution", 8, "--poses", 3,
                                   "--rays-per-pose", 64, "--variant", "lsnif", "--steps", 5,
                                   "--batch", 256, "--log2-table-size", 10, "--data", data,
                                   "--out", model, "--json", tmp_path / "t.json")
    assert code == 0, err
    shard = json.loads(next(data.glob("*.json")).read_text())
    assert shard["poses"] == [{"rest": True}] and shard["counts"]["rays"] == 3 * 64
    assert json.loads((tmp_path / "t.json").read_text())["model_bytes"] == model.stat().st_size
    code, _, err = run_batch("train", "--scene", "arm", "--data", data, "--steps", 5)
    assert code == 1 and "already holds shards" in error_lines(err)[0]


@pytest.mark.slow
def test_train_on_a_dataset_folder_creates_the_model_files_folder(tmp_path):
    """``train --data DIR --out new/folder/model.vdnif`` (docs/cli.md's example) writes the
    model into a folder it creates; a --out naming a folder is refused before training."""
    import shutil

    data = tmp_path / "data"
    shutil.copytree(REPO / "tests" / "golden" / "arm-dataset", data)
    out = tmp_path / "models" / "arm" / "arm.vdnif"
    code, printed, err = run_batch("train", "--data", data, "--steps", 2, "--batch", 256,
                                   "--log2-table-size", 12, "--device", "cpu", "--out", out)
    assert code == 0, err
    assert out.is_file() and f"model {out}" in printed
    for folder in (tmp_path / "models", tmp_path / "absent"):
        code, _, err = run_batch("train", "--data", data, "--steps", 2, "--out",
                                 str(folder) + "/")
        lines = error_lines(err)
        assert code == 1 and len(lines) == 1 and "folder, not a file" in lines[0], err
        assert str(folder) in lines[0] and "step" not in err
    assert not (tmp_path / "absent").exists()
