"""Every operator in background mode on the arm demo scene, checked on its results, and the
trained model, settings and metrics restored from the saved .blend."""

import hashlib
import importlib
import json
import math
import time

import bpy
import numpy as np
import pytest
from conftest import EXTENSION_MODULE
from mathutils import Vector

SMALL = dict(resolution=12, pose_count=4, rays_per_pose=128, steps=30, batch_size=256,
             log2_table_size=12, base_resolution=16, width=32, depth=2, use_scene_size=False,
             image_width=32, image_height=24, eval_poses=2)
PASS_IMAGES = tuple(f"VDNIF {title} ({source})" for title in ("Normal", "DiffCol", "Depth",
                                                              "IndexMA")
                    for source in ("predicted", "reference", "error"))


def module(name):
    return importlib.import_module(f"{EXTENSION_MODULE}.{name}")


def arm_scene():
    """The arm demo scene with small settings and a camera that frames it."""
    obj = module("vdnif_addon.blender.scenes").demo_scene("arm")
    for name, value in SMALL.items():
        setattr(obj.vdnif, name, value)
    corners = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
    centre = sum(corners, Vector()) / 8
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    bpy.context.scene.collection.objects.link(camera)
    camera.location = centre + Vector((0, -8, 0))
    camera.rotation_euler = (math.pi / 2, 0, 0)               # looking along +y
    bpy.context.scene.camera = camera
    bpy.context.view_layer.objects.active = obj
    return obj


def pixels(name):
    """(H, W, 4) pixels of an image, row 0 at the top."""
    image = bpy.data.images[name]
    width, height = image.size
    data = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(data)
    return data.reshape(height, width, 4)[::-1]


def eager_model(source, target):
    """The model file ``source`` changed to answer 'hit' for every segment, so a barely
    trained network still yields hit pixels and metrics over them."""
    model_file = module("vdnif_addon.model.model_file")
    network, metadata = model_file.load_model(source)
    output = network.mlp[-1]
    with __import__("torch").no_grad():
        output.weight[0] = 0.0
        output.bias[0] = 20.0                        # occlusion logit: column 0
    model_file.save_model(target, network, metadata)


@pytest.fixture(scope="module")
def session(extension, tmp_path_factory):
    """Runs every operator on the arm scene, records what they produced and saves the
    .blend; tests check the records and reopen the file."""
    folder = tmp_path_factory.mktemp("blend")
    bpy.ops.wm.read_homefile(use_empty=True)
    obj = arm_scene()
    settings = obj.vdnif
    blend = folder / "arm.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    storage = module("storage")
    record = {"blend": blend, "folder": folder}

    bpy.ops.vdnif.voxelize()
    bpy.ops.vdnif.generate_dataset()
    record["dataset"] = storage.dataset_folder(obj)
    bpy.ops.vdnif.train()
    record["trained_info"] = settings.parsed("model_info")
    plot = bpy.data.images.get("VDNIF Training (Arm)")
    record["training_plot"] = None if plot is None else (tuple(plot.size), pixels(plot.name))
    record["trained_path"] = storage.model_path(obj)
    eager = folder / "eager.vdnif"
    eager_model(record["trained_path"], eager)
    bpy.ops.vdnif.load_model(filepath=str(eager))
    bpy.ops.vdnif.render_passes()
    record["images"] = {name: pixels(name) for name in PASS_IMAGES}
    record["colorspaces"] = {name: bpy.data.images[name].colorspace_settings.name
                             for name in PASS_IMAGES}
    record["passes_files"] = sorted(path.name for path in storage.passes_folder(obj).iterdir())
    record["frame"] = bpy.context.scene.frame_current
    bpy.ops.vdnif.evaluate()
    record["metrics"] = settings.metrics
    record["packed_sha"] = hashlib.sha256(settings[storage.PACKED]).hexdigest()
    record["settings"] = {name: getattr(settings, name) for name in SMALL}
    bpy.ops.wm.save_mainfile()
    return record


def test_suggest_resolution_sets_the_suggested_one_and_says_why(empty_scene, monkeypatch):
    """The operator sets what suggest_resolution returns for the object's pose settings (here
    over two small candidates: the full search is test_resolution's) and shows the errors."""
    obj = arm_scene()
    resolution = module("vdnif_addon.blender.resolution")
    suggest, calls = resolution.suggest_resolution, []

    def small(target_obj, spec, target, _candidates, **options):
        calls.append((target_obj, spec.count, target))
        return suggest(target_obj, spec, target, (8, 16), poses=1, size=24, **options)

    monkeypatch.setattr(resolution, "suggest_resolution", small)
    bpy.ops.vdnif.suggest_resolution()
    assert calls == [(obj, 4, None)]               # the target: a share of the object's size
    assert obj.vdnif.resolution == 16               # the arm at 8 is thinner than two voxels
    assert obj.vdnif.resolution_info.startswith("suggested 16 (")
    assert "embedding error 8: " in obj.vdnif.resolution_info


def test_a_new_object_suggests_its_resolution_before_its_dataset(empty_scene, monkeypatch):
    """As ``train`` does unless told, Generate Dataset suggests the resolution first on an
    object whose resolution nobody set (Suggest reads on), and keeps it on; one whose
    resolution was set (a .blend of an earlier version, a script) keeps that resolution."""
    obj = module("vdnif_addon.blender.scenes").demo_scene("arm")
    bpy.context.view_layer.objects.active = obj
    settings = obj.vdnif
    assert settings.resolution_auto and "resolution" not in settings.keys()
    for name, value in SMALL.items():
        if name != "resolution":
            setattr(settings, name, value)
    resolution = module("vdnif_addon.blender.resolution")
    suggest, calls = resolution.suggest_resolution, []

    def small(target_obj, spec, target, _candidates, **options):
        calls.append(target_obj)
        return suggest(target_obj, spec, target, (8, 16), poses=1, size=24, **options)

    monkeypatch.setattr(resolution, "suggest_resolution", small)
    bpy.ops.vdnif.generate_dataset()
    header = json.loads(next(module("storage").dataset_folder(obj).glob("shard-*.json"))
                        .read_text())
    assert calls == [obj] and header["grid"]["resolution"] == 16 == settings.resolution
    assert settings.resolution_auto and settings.resolution_info.startswith("suggested 16 (")
    # The estimate is measured at the resolution it suggests, so that Train finds it fresh.
    bpy.ops.vdnif.estimate()
    assert calls == [obj, obj]
    assert settings.parsed("estimate_info")["settings"]["dataset"]["resolution"] == 16
    assert module("operators.training").fresh_estimate(bpy.context, obj) is not None

    settings.resolution_auto = False
    settings.resolution = 12
    bpy.ops.vdnif.generate_dataset()
    header = json.loads(next(module("storage").dataset_folder(obj).glob("shard-*.json"))
                        .read_text())
    assert calls == [obj, obj] and header["grid"]["resolution"] == 12
    other = module("vdnif_addon.blender.scenes").demo_scene("lattice")
    other.vdnif.resolution = 40                    # set, Suggest never touched: the user's
    assert not other.vdnif.resolution_auto


def test_voxelize_shows_the_occupied_cells_deformed_at_the_current_frame(empty_scene):
    obj = arm_scene()
    scene = bpy.context.scene
    bpy.ops.vdnif.voxelize()
    preview = obj.vdnif.preview
    grid = module("vdnif_addon.blender.capture_scene").capture(obj, 12, deform_corners=False).grid
    mesh = preview.data
    assert preview.parent == obj and preview.display_type == "WIRE" and preview.hide_render
    assert len(mesh.vertices) == len(grid.corners) and not mesh.polygons
    rest = np.array([v.co for v in mesh.vertices])
    edges = np.array([e.vertices for e in mesh.edges])
    lengths = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    assert np.allclose(lengths, grid.voxel_size, rtol=1e-5), "edges join neighbouring corners"
    assert len(edges) == len(module("viewer").cell_edges(
        grid.cell_corners)) > len(grid.cells)
    assert np.allclose(rest, grid.corner_positions(), atol=1e-5), "frame 1 is the rest pose"
    scene.frame_set(30)
    bpy.ops.vdnif.voxelize()
    assert obj.vdnif.preview == preview and "at frame 30" in obj.vdnif.voxel_info
    bent = np.array([v.co for v in preview.data.vertices])
    assert np.abs(bent - rest).max() > 0.3 * grid.voxel_size * 12, "the arm did not bend"
    assert len([o for o in bpy.data.objects if "VDNIF Voxels" in o.name]) == 1


def test_dataset_and_training_write_their_results(session):
    dataset = session["dataset"]
    assert dataset.parent.name == "vdnif" and dataset.parent.parent == session["folder"]
    header = json.loads(next(dataset.glob("shard-*.json")).read_text())
    assert header["object"] == "Arm" and header["counts"]["segments"] > 0
    assert len(header["poses"]) == 4 and header["grid"]["resolution"] == 12
    info = session["trained_info"]
    assert info["status"] == "completed" and info["steps"] == 30 and info["resolution"] == 12
    _, metadata = module("vdnif_addon.model.model_file").load_model(session["trained_path"])
    assert metadata.training.steps == 30 and metadata.object == "Arm"
    assert math.isfinite(info["validation"]["distance_mae"])
    size, plot = session["training_plot"]            # the loss plot, an image after Train
    assert size == (640, 360) and (plot[..., :3] < 0.5).any() and (plot[..., 3] == 1).all()


def test_render_passes_fills_the_pass_images(session):
    images = session["images"]
    for name, data in images.items():
        assert data.shape == (24, 32, 4) and np.isfinite(data).all(), name
    hit = images["VDNIF Normal (predicted)"][..., 3] > 0.5
    assert 0 < hit.sum() < hit.size, "the predicted view has hit and missed pixels"
    normals = images["VDNIF Normal (predicted)"][..., :3][hit] * 2 - 1
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-3)
    assert not np.array_equal(images["VDNIF Normal (predicted)"],
                              images["VDNIF Normal (reference)"]), "one image for both"
    assert {name for name, space in session["colorspaces"].items() if space == "sRGB"} == {
        "VDNIF DiffCol (predicted)", "VDNIF DiffCol (reference)"}
    # the files the render command writes, for the current frame, beside the .blend
    frame = f"{session['frame']:04d}"
    assert session["passes_files"] == sorted([module("vdnif_addon.output_rule").OUTPUT_MARK, *(
        f"{prefix}{name}.{frame}.{suffix}" for prefix in ("", "true-") for name, suffix in (
            ("passes", "exr"), ("hit", "png"), ("normal", "png"), ("albedo", "png"),
            ("distance", "png"), ("material", "png")))])


def test_evaluate_keeps_finite_metrics(session):
    report = json.loads(session["metrics"])
    assert report["poses"] == 2 and report["unseen_poses"] and report["resolution"] == 12
    for reference in ("vs_true", "vs_embedded"):
        metrics = report[reference]
        assert metrics["compared_rays"] > 0, reference
        for key in ("distance_mae", "distance_mae_voxels", "normal_error_deg", "hit_iou",
                    "false_negative_rate", "false_positive_rate"):
            assert math.isfinite(metrics[key]), (reference, key)
    # the eager model hits in the first cell of every ray: extras, no speed figure
    iou = report["vs_true"]["hit_iou"]
    assert iou < 0.9 and report["vs_true"]["false_positive_rate"] > 0.1
    assert report["timings"]["render_rays_per_s"] is None
    assert report["speed_withheld"] == module("vdnif_addon.inference.metrics").speed_withheld(iou)
    assert report["timings"]["prepare_pose_s"] > 0


def test_reopened_blend_restores_settings_model_and_metrics(session, extension):
    from test_ui_panels import draw_all, texts

    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    settings = obj.vdnif
    storage = module("storage")
    assert {name: getattr(settings, name) for name in SMALL} == session["settings"]
    assert settings.metrics == session["metrics"] and settings.parsed("model_info")["steps"] == 30
    assert hashlib.sha256(settings[storage.PACKED]).hexdigest() == session["packed_sha"]
    network, _ = module("vdnif_addon.model.model_file").load_model(storage.model_path(obj))
    assert network.mlp[-1].bias[0].item() == 20.0, "not the model that was kept"
    assert settings.dataset_dir.startswith("//"), "the dataset path follows the .blend"
    shown = texts(draw_all(extension))                     # the panels show what was kept
    assert "Arm: trained: proposed, 30 steps" in shown and "2 unseen poses" in shown
    assert "Model: packed in the .blend" in shown and "object units" in shown
    assert "Exact (Warp's refit BVH):" in shown and "rays/s" in shown
    bpy.ops.image.new(name="Blank")          # the pass images are not saved; render again
    bpy.context.view_layer.objects.active = obj
    bpy.ops.vdnif.render_passes()
    assert (pixels("VDNIF Normal (predicted)")[..., 3] > 0.5).sum() > 0


def test_pass_viewer_switches_pass_and_source(session):
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    screen = bpy.context.screen
    editor = next(a for a in screen.areas if a.type != "VIEW_3D")
    editor.type = "IMAGE_EDITOR"
    bpy.context.view_layer.objects.active = bpy.data.objects["Arm"]
    viewed = module("viewer").viewed()
    assert not viewed, "the view rendered in another file was kept"
    bpy.ops.vdnif.render_passes()
    viewer = bpy.context.scene.vdnif_viewer
    shown = editor.spaces.active.image.name
    assert viewer.source == "predicted" and shown == "VDNIF Normal (predicted)"
    viewer.source = "reference"
    assert editor.spaces.active.image.name == "VDNIF Normal (reference)"
    assert np.allclose(pixels("VDNIF Normal (reference)"), viewed["reference"]["normal"])
    assert not np.allclose(viewed["reference"]["normal"], viewed["predicted"]["normal"])
    assert np.allclose(pixels("VDNIF Normal (predicted)"), viewed["predicted"]["normal"])
    viewer.pass_name = "distance"
    assert editor.spaces.active.image.name == "VDNIF Depth (reference)"
    viewer.source = "error"
    assert editor.spaces.active.image.name == "VDNIF Depth (error)"
    assert np.allclose(pixels("VDNIF Depth (error)"), viewed["error"]["distance"])
    assert np.allclose(pixels("VDNIF Depth (predicted)"), viewed["predicted"]["distance"])
    assert np.allclose(pixels("VDNIF Depth (reference)"), viewed["reference"]["distance"])


def test_ao_toggle_renders_and_evaluates_the_secondary_passes(session):
    """With the AO pass toggle on, Render Passes casts the AO and shadow rays of the object's
    AO samples and distance: their images (reference, predicted, error), their PNGs and their
    passes in the frame's EXR (Shadow too only with its own toggle). An AO distance below the
    exact hits' offset meets nothing: the reference's AO is 1 on every hit, exactly. Evaluate
    then reports the AO and shadow errors. Which pass the viewer shows decides nothing."""
    from blender_exr import pass_names

    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    viewer = bpy.context.scene.vdnif_viewer
    settings = module("vdnif_addon.settings")
    assert (obj.vdnif.ao_samples, obj.vdnif.ao_distance) == (
        settings.AO_SAMPLES, pytest.approx(settings.AO_DISTANCE))
    assert not obj.vdnif.pass_ao and not obj.vdnif.pass_shadow, "off by default"
    viewer.pass_name = "ao"                          # viewing AO casts nothing
    bpy.ops.vdnif.render_passes()
    assert not module("viewer").viewed("ao") and "VDNIF AO (predicted)" not in bpy.data.images
    folder = module("storage").passes_folder(obj)
    frame = f"{bpy.context.scene.frame_current:04d}"
    exr = folder / f"passes.{frame}.exr"
    assert not {"AO", "Shadow"} & pass_names(exr)
    viewer.pass_name = "normal"
    obj.vdnif.pass_ao, obj.vdnif.ao_samples = True, 4
    bpy.ops.vdnif.render_passes()
    viewed = module("viewer").viewed("ao")
    hit = {source: viewed[source]["normal"][..., 3] > 0.5 for source in ("reference",
                                                                         "predicted")}
    assert hit["reference"].sum() > 10
    for source in ("reference", "predicted", "error"):
        for name in ("AO", "Shadow"):
            image = pixels(f"VDNIF {name} ({source})")
            assert image.shape == (24, 32, 4) and np.isfinite(image).all(), (name, source)
    for source in ("reference", "predicted"):
        image = pixels(f"VDNIF AO ({source})")
        np.testing.assert_array_equal(image[..., 3] > 0.5, hit[source])
        ao = image[..., 0][hit[source]]
        assert ao.min() >= 0 and ao.max() <= 1
        np.testing.assert_allclose(ao * 4, np.round(ao * 4), atol=1e-6)     # 4 rays each
    files = {path.name for path in folder.iterdir()}
    assert {f"{prefix}ao.{frame}.png" for prefix in ("", "true-")} <= files
    assert not any(name.startswith(("ao", "shadow", "true-ao")) and name.endswith(".exr")
                   for name in files), "no EXR of their own"
    assert {"AO"} <= pass_names(exr) and "Shadow" not in pass_names(exr)
    obj.vdnif.pass_shadow = True
    obj.vdnif.ao_distance = settings.BOUNDS["ao_distance"][0]
    bpy.ops.vdnif.render_passes()
    np.testing.assert_array_equal(pixels("VDNIF AO (reference)")[..., 0][hit["reference"]], 1)
    for path in (exr, folder / f"true-passes.{frame}.exr"):
        assert {"AO", "Shadow"} <= pass_names(path), path
    viewer.pass_name = "shadow"                      # rendered with AO: shown at once
    assert module("viewer").viewed("shadow")
    bpy.ops.vdnif.evaluate()
    report = json.loads(obj.vdnif.metrics)
    for reference in ("vs_true", "vs_embedded"):
        for key in ("ao_mae", "ao_mae_true_hit", "shadow_false_lit_rate",
                    "shadow_false_shadow_rate"):
            assert math.isfinite(report[reference][key]), (reference, key)
    assert report["secondary"]["ao_samples"] == 4
    assert report["secondary"]["network_offset"] > report["secondary"]["offset"]
    assert report["timings"]["exact_rays_per_s"] > 0


def test_the_chosen_precision_reaches_the_evaluation_or_is_refused(session, monkeypatch):
    """The Passes panel's Precision: Evaluate runs the network in it (its report says so);
    bfloat16 on a device without bfloat16 instructions (made so here, as it is made to
    have them first) fails in one line naming the reason and keeps the last metrics."""
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    runtime = module("vdnif_addon.kernels.runtime")
    assert obj.vdnif.precision == module("vdnif_addon.settings").DEFAULT_PRECISION
    monkeypatch.setattr(runtime, "bfloat16_native", lambda device: True)
    obj.vdnif.precision = "bfloat16"
    bpy.ops.vdnif.evaluate()
    kept = obj.vdnif.metrics
    assert json.loads(kept)["precision"] == "bfloat16"
    monkeypatch.setattr(runtime, "bfloat16_native", lambda device: False)
    with pytest.raises(RuntimeError, match="has no bfloat16 instructions"):
        bpy.ops.vdnif.evaluate()
    assert obj.vdnif.metrics == kept and "bfloat16" in obj.vdnif.last_error


def test_viewport_view_renders_the_3d_viewports_perspective(session):
    """The hits lie where the viewport's projection puts the object (pinhole through the
    pixel centres, the view's horizontal angle, the image's aspect)."""
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    view = next(a for a in bpy.context.screen.areas if a.type == "VIEW_3D").spaces.active.region_3d
    width, height = obj.vdnif.image_width, obj.vdnif.image_height = 128, 96
    bpy.context.scene.camera = None
    with pytest.raises(RuntimeError, match="The scene has no active camera"):
        bpy.ops.vdnif.render_passes()
    obj.vdnif.view = "VIEWPORT"
    bpy.ops.vdnif.render_passes()
    viewed = module("viewer").viewed()
    hit = viewed["reference"]["normal"][..., 3] > 0.5
    assert hit.sum() > 10
    centre = sum((obj.matrix_world @ Vector(c) for c in obj.bound_box), Vector()) / 8
    x, y, z = view.view_matrix @ centre
    half = 1 / view.window_matrix[0][0]                      # tan of half the view angle
    column = (x / -z / half + 1) / 2 * width
    row = (1 - y / -z / (half * height / width)) / 2 * height
    rows, columns = np.nonzero(hit)
    assert abs(columns.mean() + 0.5 - column) < 2 and abs(rows.mean() + 0.5 - row) < 4
    view.is_perspective = False
    with pytest.raises(RuntimeError, match="orthographic"):
        bpy.ops.vdnif.render_passes()
    assert "'Arm'" in obj.vdnif.last_error and "orthographic" in obj.vdnif.last_error


def test_save_and_load_model_files(session, tmp_path):
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    storage = module("storage")
    exported = tmp_path / "copy.vdnif"
    bpy.ops.vdnif.save_model(filepath=str(exported))
    assert exported.read_bytes() == bytes(obj.vdnif[storage.PACKED])
    settings = obj.vdnif
    settings.model_storage = "FILE"
    settings.width = 7
    bpy.ops.vdnif.load_model(filepath=str(session["trained_path"]))
    assert storage.PACKED not in settings and settings.model_path == "//vdnif/Arm.vdnif"
    assert storage.model_path(obj).read_bytes() == session["trained_path"].read_bytes()
    assert settings.width == 32, "the loaded model's settings were not adopted"
    assert settings.metrics == "" and settings.parsed("model_info")["steps"] == 30
    assert storage.loaded_model(obj) == str(session["trained_path"])   # Train asks first
    bpy.ops.vdnif.render_passes()                     # the loaded model renders

    corrupt = tmp_path / "corrupt.vdnif"
    corrupt.write_bytes(b"not a model")
    with pytest.raises(RuntimeError, match="corrupt.vdnif cannot be read"):
        bpy.ops.vdnif.load_model(filepath=str(corrupt))
    assert storage.model_path(obj).read_bytes() == session["trained_path"].read_bytes()
    bpy.ops.mesh.primitive_cube_add()
    with pytest.raises(RuntimeError, match="trained on 'Arm'.*not on 'Cube'"):
        bpy.ops.vdnif.load_model(filepath=str(exported))


def test_failed_training_is_reported_and_keeps_the_model(session):
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    bpy.context.view_layer.objects.active = obj
    storage = module("storage")
    kept = bytes(obj.vdnif[storage.PACKED])
    obj.vdnif.base_resolution = 65536                      # finest level 131072 cells
    with pytest.raises(RuntimeError, match="'Arm': .*finest resolution 131072"):
        bpy.ops.vdnif.train()
    assert bytes(obj.vdnif[storage.PACKED]) == kept and "131072" in obj.vdnif.last_error
    obj.vdnif.base_resolution, obj.vdnif.variant = 16, "lsnif"
    bpy.ops.vdnif.train()       # one button: the dataset is made again for the variant
    info = obj.vdnif.parsed("dataset_info")
    assert info["variant"] == "lsnif" and info["poses"] == 1 and info["bytes"] > 0
    assert obj.vdnif.parsed("model_info")["variant"] == "lsnif"


def test_file_storage_needs_a_saved_blend(session, empty_scene):
    obj = arm_scene()
    obj.vdnif.model_storage = "FILE"
    with pytest.raises(RuntimeError, match="'Arm': save the .blend first"):
        bpy.ops.vdnif.load_model(filepath=str(session["trained_path"]))
    assert not module("storage").has_model(obj)


class OperatorStandIn:
    """A ``self`` for the Train operator's methods (operators cannot be instanced): the
    class's functions bound to it, reports recorded."""

    def __init__(self, cls, **attributes):
        self.cls, self.reports = cls, []
        self.__dict__.update(attributes)

    def __getattr__(self, name):
        value = getattr(self.cls, name)
        return value.__get__(self) if hasattr(value, "__get__") else value    # bl_label

    def report(self, kind, message):
        self.reports.append((set(kind), message))


def modal_run(operator_class, name, esc_when=None, **properties):
    """Drives a JobOperator's modal glue by hand (timers never fire in the bpy module): its
    stages start as Blender's invoke would, timer events tick them, Esc cancels once
    ``esc_when(job state)`` holds. Returns (result, status texts, reports)."""
    from types import SimpleNamespace

    running = module("operators.running")
    jobs = module("operators.common").JOBS
    status, removed = [], []
    context = SimpleNamespace(
        screen=None, workspace=SimpleNamespace(status_text_set=status.append),
        window_manager=SimpleNamespace(event_timer_remove=removed.append))
    timer = object()
    operator = OperatorStandIn(operator_class, _name=name, _timer=timer, **properties)
    obj = bpy.data.objects[name]
    operator._stages = list(operator_class.stages(operator, bpy.context, obj))
    operator._next(obj)
    running._timers.append(timer)
    tick = SimpleNamespace(type="TIMER", value="NOTHING")
    while (result := operator.modal(context, tick)) == {"PASS_THROUGH"}:
        if esc_when is not None and esc_when(jobs[name].state):
            assert operator.modal(context, SimpleNamespace(type="ESC", value="PRESS")) == {
                "RUNNING_MODAL"}
            esc_when = None
        time.sleep(0.05)
    assert removed == [timer] and not jobs and running._timers == [] and status[-1] is None
    return result, status[:-1], operator.reports


def test_modal_train_esc_keeps_the_previous_model_unless_asked(session):
    """Esc cancels the worker; the previous model stays unless Keep Partial Model on Cancel
    is on, then the network of the last finished step becomes the object's model."""
    bpy.ops.wm.open_mainfile(filepath=str(session["blend"]))
    obj = bpy.data.objects["Arm"]
    obj.vdnif.steps = 1000
    storage = module("storage")
    kept = bytes(obj.vdnif[storage.PACKED])
    train = module("operators.training").VDNIF_OT_train
    result, status, reports = modal_run(train, "Arm", lambda state: state.step >= 20)
    assert result == {"FINISHED"} and bytes(obj.vdnif[storage.PACKED]) == kept
    assert any("loss" in text and "Esc cancels" in text for text in status)
    assert len(reports) == 1 and reports[0][0] == {"INFO"}
    assert "partial model dropped): the previous model is kept" in reports[0][1]

    obj.vdnif.keep_partial_model = True
    result, _, reports = modal_run(train, "Arm", lambda state: state.step >= 20)
    info = obj.vdnif.parsed("model_info")
    assert result == {"FINISHED"} and info["status"] == "cancelled"
    assert 20 <= info["steps"] < 1000
    assert f"'Arm': cancelled after {info['steps']} steps" in reports[0][1]
    network, _ = module("vdnif_addon.model.model_file").load_model(storage.model_path(obj))
    assert network.mlp[-1].bias[0].item() != 20.0, "the new model replaced the old one"
