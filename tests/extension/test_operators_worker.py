"""The long operators run in workers: Blender's data is read on the main thread only (a job
computes the same dataset after its object was deleted), progress and ETA reach the status
bar, cancel keeps what was there, the worker's results equal the synchronous run's, and
the one Train button builds a missing dataset first after measuring its estimate."""

import json
import re
import time

import bpy
import numpy as np
import pytest
from test_ui_panels import BoundTo, RecordingLayout, draw_all, texts
from test_ui_workflow import arm_scene, eager_model, modal_run, module

CORNERS = "VDNIF corners"      # the helper objects reading the poses makes


@pytest.fixture(scope="module")
def trained(extension, tmp_path_factory):
    """A saved .blend whose arm was trained from scratch by the one Train button (dataset
    included), then given a model that hits everywhere (metrics need hits)."""
    folder = tmp_path_factory.mktemp("worker")
    bpy.ops.wm.read_homefile(use_empty=True)
    obj = arm_scene()
    blend = folder / "arm.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    storage = module("storage")
    assert not storage.has_dataset(obj) and not storage.has_model(obj)
    bpy.ops.vdnif.train()
    record = {"dataset_info": obj.vdnif.parsed("dataset_info"),
              "dataset_settings": module("operators.scene").dataset_settings(obj),
              "model_info": obj.vdnif.parsed("model_info")}
    eager_model(storage.model_path(obj), folder / "eager.vdnif")
    bpy.ops.vdnif.load_model(filepath=str(folder / "eager.vdnif"))
    bpy.ops.wm.save_mainfile()
    return blend, record


def reopen(blend):
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    return obj


def shards(folder):
    """{shard file name: its arrays} of a dataset folder."""
    return {path.name: dict(np.load(path)) for path in sorted(folder.glob("shard-*.npz"))}


def test_dataset_job_computes_on_what_the_main_thread_read(empty_scene, tmp_path):
    """The main thread reads every pose; the object is then deleted, and the worker still
    writes exactly the dataset the batch path writes from the live object."""
    obj = arm_scene()
    obj.vdnif.pose_count = 3                          # within the feed: all read ahead
    capture = module("vdnif_addon.blender.capture_scene").capture
    captured = capture(obj, 12, obj.vdnif.pose_spec(), deform_corners=False)
    steps = module("vdnif_addon.blender.steps")
    steps.variant_dataset(obj, captured, "proposed", tmp_path / "batch", 128, seed=5)
    job = module("vdnif_addon.blender.ui_jobs").dataset_job(
        obj, captured, "proposed", tmp_path / "worker", 128, seed=5)
    for _ in range(10):
        job.tick()
    assert not [o for o in bpy.data.objects if CORNERS in o.name], "the reads cleaned up"
    bpy.data.objects.remove(obj)
    job.start()
    state = job.join(timeout=120)
    assert state.status == "completed", state.message
    batch, worker = shards(tmp_path / "batch"), shards(tmp_path / "worker")
    assert list(batch) == list(worker) and batch
    for name, arrays in batch.items():
        assert arrays.keys() == worker[name].keys()
        for key, values in arrays.items():
            assert np.array_equal(values, worker[name][key]), (name, key)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["batch", "worker"], "no partial left"


@pytest.mark.slow
def test_one_train_button_builds_the_dataset_then_trains(trained):
    _, record = trained
    info = record["dataset_info"]
    assert info["settings"] == record["dataset_settings"] and info["bytes"] > 0
    assert info["poses"] == 4 and info["resolution"] == 12
    assert record["model_info"]["status"] == "completed" and record["model_info"]["steps"] == 30


def held_after_first_pose(monkeypatch):
    """Holds the dataset job's worker after its first pose until it is cancelled (its
    progress call raises then), so that Esc lands mid-run however fast the machine."""
    ui_jobs = module("vdnif_addon.blender.ui_jobs")
    generate = ui_jobs.generate_dataset

    def held(*args, progress, **options):
        def hold(done, total):
            progress(done, total)
            while done == 1:
                time.sleep(0.01)
                progress(done, total)

        return generate(*args, progress=hold, **options)

    monkeypatch.setattr(ui_jobs, "generate_dataset", held)


@pytest.mark.slow
def test_generate_dataset_in_a_worker_and_cancel_keeps_the_previous(trained, monkeypatch):
    blend, _ = trained
    obj = reopen(blend)
    storage = module("storage")
    folder = storage.dataset_folder(obj)
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    info = obj.vdnif.dataset_info
    obj.vdnif.rays_per_pose = 256
    generate = module("operators.scene").VDNIF_OT_generate_dataset
    with monkeypatch.context() as patched:
        held_after_first_pose(patched)
        result, status, reports = modal_run(
            generate, "Arm", lambda state: state.title == "dataset" and state.count >= 1)
    assert result == {"FINISHED"} and "previous dataset is kept" in reports[0][1]
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == before
    assert obj.vdnif.dataset_info == info
    assert any("dataset: 1/4 poses, ETA" in text and "Esc cancels" in text for text in status)

    result, status, reports = modal_run(generate, "Arm")
    counts = [int(text.split("dataset: ")[1].split("/")[0]) for text in status
              if "dataset: " in text and "/4 poses" in text]
    assert result == {"FINISHED"} and counts and counts == sorted(counts)
    assert obj.vdnif.parsed("dataset_info")["rays"] == 4 * 256
    assert [p.name for p in folder.parent.iterdir() if p.name.endswith(".partial")] == []


@pytest.mark.slow
def test_evaluate_and_render_passes_in_a_worker_match_the_synchronous_run(trained):
    blend, _ = trained
    obj = reopen(blend)
    bpy.ops.vdnif.evaluate()
    synchronous = json.loads(obj.vdnif.metrics)
    obj.vdnif.metrics = ""
    passes = module("operators.passes")
    result, status, _ = modal_run(passes.VDNIF_OT_evaluate, "Arm")
    worker = json.loads(obj.vdnif.metrics)
    assert result == {"FINISHED"} and worker["vs_true"] == synchronous["vs_true"]
    assert worker["vs_embedded"] == synchronous["vs_embedded"]
    assert any(re.search(r"evaluation: [01]/2 poses", text) for text in status)

    viewer = module("viewer")
    bpy.ops.vdnif.render_passes()
    shown = {source: {name: image.copy() for name, image in images.items()}
             for source, images in viewer.viewed().items()}
    viewer.viewed().clear()
    result, _, reports = modal_run(passes.VDNIF_OT_render_passes, "Arm")
    assert result == {"FINISHED"} and "pixels hit" in reports[0][1]
    for source, images in shown.items():
        for name, image in images.items():
            assert np.array_equal(viewer.viewed()[source][name], image), (source, name)


@pytest.mark.slow
def test_a_deleted_object_ends_the_job_with_a_warning(trained):
    blend, _ = trained
    obj = reopen(blend)
    generate = module("operators.scene").VDNIF_OT_generate_dataset
    obj.vdnif.rays_per_pose = 256
    deleted = []

    def delete_once(state):
        if not deleted:
            bpy.data.objects.remove(bpy.data.objects["Arm"])
            deleted.append(True)
        return False

    result, _, reports = modal_run(generate, "Arm", delete_once)
    assert result == {"CANCELLED"} and reports == [({"WARNING"},
                                                    "'Arm' is gone; its results are not kept")]
    assert not [o for o in bpy.data.objects if CORNERS in o.name]


@pytest.mark.slow
def test_estimate_of_disk_against_a_real_dataset(empty_scene, extension, tmp_path):
    """The estimate (bytes per segment x expected segments, from a sample) against the
    dataset that the same settings then write, and what Train shows before it starts."""
    obj = arm_scene()
    obj.vdnif.pose_count, obj.vdnif.rays_per_pose, obj.vdnif.resolution = 8, 2048, 16
    bpy.ops.vdnif.estimate()
    figures = json.loads(obj.vdnif.estimate_info)["figures"]
    training = module("operators.training")
    assert training.fresh_estimate(bpy.context, obj) == figures
    describe = module("vdnif_addon.posed.estimate").describe
    shown = texts(draw_all(extension))
    assert describe(figures) in shown and "operator:vdnif.train" in shown
    record = []                                  # Train's confirm dialog shows it too
    training.VDNIF_OT_train.draw(BoundTo(training.VDNIF_OT_train, RecordingLayout(record)),
                                 bpy.context)
    size = module("vdnif_addon.posed.estimate").size_text(figures["bytes"])
    dialog = texts({"dialog": record})
    assert f"Dataset: about {size} in " in dialog and describe(figures).capitalize() in dialog
    bpy.ops.vdnif.generate_dataset()
    folder = module("storage").dataset_folder(obj)
    real = sum(path.stat().st_size for path in folder.iterdir())
    segments = obj.vdnif.parsed("dataset_info")["segments"]
    print(f"estimate {figures['bytes']} bytes, {figures['segments']} segments, "
          f"{figures['dataset_s']:.2f} s; real {real} bytes, {segments} segments")
    assert abs(figures["bytes"] / real - 1) < 0.15
    assert abs(figures["segments"] / segments - 1) < 0.15
    assert figures["dataset_s"] > 0 and figures["train_s"] > 0
    obj.vdnif.rays_per_pose = 1024
    assert training.fresh_estimate(bpy.context, obj) is None, "estimated for other settings"
    assert "operator:vdnif.estimate" in texts(draw_all(extension))


@pytest.mark.slow
def test_suggest_resolution_in_a_worker_equals_the_direct_search(empty_scene, monkeypatch):
    """The worker asks the main thread for each candidate's capture and poses: the same
    embedding errors as the search run in one thread, and no helper object left."""
    obj = arm_scene()
    monkeypatch.setattr(module("vdnif_addon.settings"), "RESOLUTION_CANDIDATES", (8, 16))
    resolution = module("vdnif_addon.blender.resolution")
    direct = resolution.suggest_resolution(obj, obj.vdnif.pose_spec(), None, (8, 16))
    suggest = module("operators.scene").VDNIF_OT_suggest_resolution
    result, status, reports = modal_run(suggest, "Arm")
    assert result == {"FINISHED"} and obj.vdnif.resolution == direct.resolution
    assert obj.vdnif.resolution_info == f"suggested {direct.describe()}"
    assert any(re.search(r"suggestion: [01]/2 resolutions", text) for text in status)
    assert not [o for o in bpy.data.objects if CORNERS in o.name]
