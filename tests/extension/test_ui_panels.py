"""The sidebar panels draw against a recording layout in every state (no object, no torch,
no model, training, trained, error), and the operators refuse bad input with a reason."""

import dataclasses
import itertools
import json

import bpy
import pytest

UILAYOUT = bpy.types.UILayout.bl_rna.functions
ICONS = set(UILAYOUT["label"].parameters["icon"].enum_items.keys())
SUBLAYOUTS = {"row", "column", "box", "split", "grid_flow", "column_flow"}


class RecordingLayout:
    """Stands in for UILayout: records what a panel draws and checks every call against
    Blender's own definitions (the function and its keywords exist, properties exist on
    their data, operators are registered, icons are valid). An operator button drawn where
    a layout or one around it is disabled (``enabled = False``) is recorded with
    ``enabled=False`` among its keywords."""

    def __init__(self, record, inherited=True):
        object.__setattr__(self, "record", record)
        object.__setattr__(self, "inherited", inherited)    # every layout around it enabled
        object.__setattr__(self, "own", True)

    def __setattr__(self, name, value):
        assert name in bpy.types.UILayout.bl_rna.properties, f"UILayout has no '{name}'"
        if name == "enabled":
            object.__setattr__(self, "own", bool(value))

    def __getattr__(self, name):
        assert name in UILAYOUT, f"UILayout has no function '{name}'"
        allowed = set(UILAYOUT[name].parameters.keys())

        def call(*args, **kwargs):
            assert set(kwargs) <= allowed, f"{name}() takes no {set(kwargs) - allowed}"
            assert kwargs.get("icon", "NONE") in ICONS, f"no icon {kwargs['icon']}"
            enabled = self.inherited and self.own
            if name in SUBLAYOUTS:
                return RecordingLayout(self.record, enabled)
            if name == "prop":
                data, prop = args
                assert prop in data.bl_rna.properties, f"no property '{prop}' on {data}"
            if name == "operator":
                category, operator = args[0].split(".")
                rna = getattr(getattr(bpy.ops, category), operator).get_rna_type()
            if name == "progress":
                assert 0 <= kwargs["factor"] <= 1
            key = {"prop": args[1:2], "operator": args[:1]}.get(name) or [kwargs.get("text")]
            self.record.append((name, key[0], kwargs if enabled or name != "operator"
                                else dict(kwargs, enabled=False)))
            return OperatorSettings(rna) if name == "operator" else None

        return call


class OperatorSettings:
    """Stands in for the properties of an operator button: only its own can be set."""

    def __init__(self, rna):
        object.__setattr__(self, "rna", rna)

    def __setattr__(self, name, value):
        assert name in self.rna.properties, f"{self.rna.identifier} has no property '{name}'"


class BoundTo:
    """A stand-in ``self`` for a panel class's methods (panels cannot be instanced)."""

    def __init__(self, cls, layout):
        self.cls, self.layout = cls, layout

    def __getattr__(self, name):
        value = getattr(self.cls, name)
        return value.__get__(self) if callable(value) and hasattr(value, "__get__") else value


def draw_all(extension):
    """Draws every panel whose poll passes; returns {panel: recorded calls}."""
    drawn = {}
    for cls in extension.panels.sidebar.classes:
        if hasattr(cls, "poll") and not cls.poll(bpy.context):
            continue
        record = []
        cls.draw(BoundTo(cls, RecordingLayout(record)), bpy.context)
        drawn[cls.__name__] = record
    return drawn


def texts(drawn):
    """Every label text (wrapped lines joined again) and 'operator:' / 'prop:' name drawn,
    as one string."""
    return " ".join(call[1] if call[0] == "label" else f"{call[0]}:{call[1]}"
                    for record in drawn.values() for call in record)


@pytest.fixture
def arm(empty_scene, core):
    obj = core("blender.scenes").demo_scene("arm")
    bpy.context.view_layer.objects.active = obj
    return obj


def test_no_object_and_no_mesh(empty_scene, extension):
    drawn = draw_all(extension)
    assert list(drawn) == ["VDNIF_PT_main"] and "Select a mesh object" in texts(drawn)
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    bpy.context.scene.collection.objects.link(camera)
    bpy.context.view_layer.objects.active = camera
    assert "'Cam' is a camera, not a mesh" in texts(draw_all(extension))


def test_no_torch_says_what_to_do(arm, extension, monkeypatch):
    monkeypatch.setattr(extension.preferences, "torch_available", lambda: False)
    drawn = draw_all(extension)
    main = texts({"main": drawn["VDNIF_PT_main"]})
    assert "PyTorch is not installed" in main and "operator:vdnif.install_dependencies" in main
    assert "Install PyTorch" in main, "the hint names the preferences button"
    assert "PyTorch is not installed" in texts({"d": drawn["VDNIF_PT_dataset"]}), (
        "the Generate Dataset button says why it is unavailable")
    assert not bpy.ops.vdnif.generate_dataset.poll()
    with pytest.raises(RuntimeError, match="PyTorch is not installed"):
        bpy.ops.vdnif.train()


def test_no_model_yet(arm, extension):
    drawn = draw_all(extension)
    assert set(drawn) == {cls.__name__ for cls in extension.panels.sidebar.classes}
    everything = texts(drawn)
    assert "Arm: no model yet" in everything
    assert "Generates the dataset first (its size and time are shown before it starts)" in \
        everything and "operator:vdnif.estimate" in everything
    assert "'Arm' has no trained model" in everything
    assert "Render the passes to fill the images" in everything
    scene = bpy.context.scene
    assert "operator:vdnif.render_animation" in everything and (
        f"Frames {scene.frame_start}..{scene.frame_end}, step 1") in everything
    with pytest.raises(RuntimeError, match="'Arm' runs no job"):
        bpy.ops.vdnif.cancel_job()
    arm.vdnif.variant = "lsnif"                   # a variant brings its positional bands
    assert arm.vdnif.pe_bands == 0
    arm.vdnif.variant = "proposed"
    assert arm.vdnif.pe_bands == 3
    shown = {call[1] for record in drawn.values() for call in record if call[0] == "prop"}
    assert {"resolution", "pose_source", "pose_count", "seed", "max_angle", "rays_per_pose",
            "variant", "levels", "base_resolution", "log2_table_size", "feature_dim",
            "pe_bands", "width", "depth", "steps", "batch_size", "device", "view",
            "pass_name", "source", "model_storage", "keep_partial_model", "use_scene_frames",
            "frames_dir", "live_preview", "preview_percent", "use_scene_size", "pass_ao",
            "pass_shadow"} <= shown


def test_training_shows_progress_and_cancel(arm, extension, core, tmp_path):
    job = core("training.job").TrainingJob(tmp_path, "proposed", tmp_path / "m.vdnif",
                                           {"steps": 200})
    job.state.step, job.state.loss, job.state.eta_s = 50, 0.5, 30
    extension.operators.common.JOBS["Arm"] = job
    try:
        drawn = draw_all(extension)
        assert bpy.ops.vdnif.cancel_job.poll() and not bpy.ops.vdnif.train.poll()
        bpy.ops.vdnif.cancel_job()
        assert job.state.cancelling
    finally:
        extension.operators.common.JOBS.clear()
    progress = [call for call in drawn["VDNIF_PT_main"] if call[0] == "progress"]
    assert progress[0][2]["factor"] == 0.25 and "step 50/200" in progress[0][2]["text"]
    assert "operator:vdnif.cancel_job" in texts(drawn)
    assert "operator:vdnif.train" not in texts(drawn), "the progress takes Train's place"
    assert "Arm: busy: step 50/200" in texts(drawn)
    assert "'Arm' is busy (step 50/200" in texts(drawn), "Voxelize says why it waits"


def test_trained_and_evaluated(arm, extension):
    settings = arm.vdnif
    settings[extension.storage.PACKED] = b"\x00" * 250_000
    settings.model_info = json.dumps({"variant": "proposed", "resolution": 16,
                                      "status": "completed", "steps": 40,
                                      "validation": {"distance_mae_voxels": 0.25,
                                                     "normal_error_deg": 9.5}})
    metrics = {"distance_mae": 0.02, "distance_mae_voxels": 0.64, "normal_error_deg": 12.0,
               "hit_iou": 0.9, "false_negative_rate": 0.0046, "false_positive_rate": 0.088,
               "albedo_psnr": 31.25, "material_accuracy": None}
    settings.metrics = json.dumps({"poses": 2, "unseen_poses": True, "width": 32,
                                   "height": 24, "variant": "proposed", "vs_true": metrics,
                                   "vs_embedded": dict(metrics, distance_mae=None),
                                   "timings": {"render_rays_per_s": 12345.0,
                                               "exact_rays_per_s": 67890.0}})
    bpy.data.images.new("VDNIF Training (Arm)", 4, 4)
    everything = texts(draw_all(extension))
    assert "Loss plot: image 'VDNIF Training (Arm)' (Image Editor)" in everything
    assert "Arm: trained: proposed, 40 steps" in everything
    assert "Model: packed in the .blend (0.25 MB)" in everything
    assert "distance error 0.25 voxels, normal error 9.5 deg" in everything
    assert "2 unseen poses, 32x24, proposed" in everything
    assert ("distance MAE 0.02 object units (0.64 voxels), normal error 12 deg, hit IoU 0.9, "
            "false negatives 0.46 %, false positives 8.8 %, albedo PSNR 31.25 dB, "
            "material accuracy n/a") in everything, "the panel prints the batch line"
    assert "distance MAE n/a" in everything and "Network: 12,345 rays/s" in everything
    assert "Exact (Warp's refit BVH): 67,890 rays/s" in everything    # beside it
    assert "Embree" in everything and "docs/performance.md" in everything
    assert "Verdict: speckled: 0.46 % holes, 8.8 % extras" in everything
    assert "has no trained model" not in everything
    report = json.loads(settings.metrics)
    report.update(timings={"render_rays_per_s": None},
                  speed_withheld="hit IoU 0.500 against the true reference is below 0.9: the "
                                 "model does not predict hits")
    settings.metrics = json.dumps(report)
    everything = texts(draw_all(extension))
    assert f"Network: n/a, {report['speed_withheld']}" in everything
    assert "rays/s" not in everything, "no exact path's speed in this report either"


def test_error_is_shown_until_the_next_success(arm, extension):
    with pytest.raises(RuntimeError, match="'Arm' has no trained model"):
        bpy.ops.vdnif.evaluate()
    message = "'Arm': a long explanation of what went wrong " * 3
    arm.vdnif.last_error = message
    main = draw_all(extension)["VDNIF_PT_main"]
    start = next(i for i, call in enumerate(main) if call[2].get("icon") == "ERROR")
    lines = [main[start], *itertools.takewhile(lambda call: call[2].get("icon") == "BLANK1",
                                               main[start + 1:])]
    assert len(lines) > 1, "wrapped over lines"
    assert " ".join(call[1] for call in lines) == message.strip()
    bpy.ops.vdnif.voxelize()
    assert arm.vdnif.last_error == "" and "ERROR" not in str(draw_all(extension))


def test_operators_refuse_bad_input(empty_scene, extension):
    mesh = bpy.data.meshes.new("Empty")
    obj = bpy.data.objects.new("Empty", mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    for operator in ("voxelize", "generate_dataset", "train", "render_passes", "evaluate",
                     "save_model", "load_model", "cancel_job", "render_animation",
                     "estimate"):
        with pytest.raises(RuntimeError, match="'Empty' has no faces"):
            getattr(bpy.ops.vdnif, operator)()


def test_a_declared_property_is_drawn_in_the_panel_it_names(arm, extension, core, monkeypatch):
    """A setting declared with a panel property and a ``section`` (a new one, with no layout
    line of its own) is drawn by that panel: here the encoder's levels, moved to Passes."""
    declarations = core("declarations")

    def props(panel):
        return [call[1] for call in draw_all(extension)[panel] if call[0] == "prop"]

    assert "levels" not in props("VDNIF_PT_passes")
    setting, panel = declarations.panel_properties()["levels"]
    moved = {"levels": (setting, dataclasses.replace(panel, section="VDNIF_PT_passes"))}
    monkeypatch.setattr(declarations, "panel_properties", lambda: moved)
    assert props("VDNIF_PT_passes")[-1] == "levels"
