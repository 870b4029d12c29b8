"""Animation: frame ranges as Blender takes them, ``render --frames`` writing image sequences
from one loaded model (each frame equal to a single ``--frame`` render of it), Render
Animation over the scene's range or the object's, cancelled part-way, and the live preview's
drop-frames rule on timeline changes."""

import json
import re
import time

import bpy
import numpy as np
import pytest
from test_operators_worker import reopen, trained  # noqa: F401 - a fixture
from test_ui_workflow import modal_run, module

SIZE = ("--width", "16", "--height", "12")


def image_pixels(path):
    """(H, W, 4) float pixels of an image file read with Blender's image API."""
    image = bpy.data.images.load(str(path))
    try:
        width, height = image.size
        data = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(data)
        return data.reshape(height, width, 4)
    finally:
        bpy.data.images.remove(image)


def sequence(folder, stem="normal", suffix=".png"):
    """The frame numbers of the ``stem`` image sequence in ``folder`` (``normal.0001.png``)."""
    return sorted(int(path.name[len(stem) + 1:-len(suffix)])
                  for path in folder.glob(f"{stem}.*{suffix}"))


def test_frame_ranges_parse_like_blenders(extension):
    animation = module("vdnif_addon.posed.animation")
    errors = module("vdnif_addon.errors")
    assert animation.parse_frames("1:5") == [1, 2, 3, 4, 5]
    assert animation.parse_frames("1:9:4") == [1, 5, 9]
    assert animation.parse_frames("-2:1:2") == [-2, 0]
    for text, problem in (("5:1", "ends before it starts"), ("1:5:0", "at least 1"),
                          ("a:b", "START:END"), ("3", "START:END"), ("1.5:3", "whole")):
        with pytest.raises(errors.VDNIFError, match=problem):
            animation.parse_frames(text)
    steps = module("vdnif_addon.blender.steps")
    assert steps.frame_number(7) == ".0007" and steps.frame_number(12345) == ".12345"
    assert steps.frame_number(-3) == ".-003" and steps.frame_number(None) == ""


@pytest.mark.slow
def test_render_frames_writes_sequences_from_one_loaded_model(trained, tmp_path,  # noqa: F811
                                                              monkeypatch, capsys):
    blend, _ = trained
    obj = reopen(blend)
    model = tmp_path / "arm.vdnif"
    bpy.ops.vdnif.save_model(filepath=str(model))
    model_file = module("vdnif_addon.model.model_file")
    loads, load = [], model_file.load_model
    monkeypatch.setattr(model_file, "load_model", lambda path: loads.append(path) or load(path))
    cli = module("vdnif_addon.cli")
    scene = ("--blend", str(blend), "--object", obj.name, "--model", str(model))
    out = tmp_path / "frames"
    assert cli.main(["render", *scene, "--frames", "1:5:2", *SIZE, "--out", str(out)]) == 0
    assert len(loads) == 1, "the model is read once for the whole range"
    assert "frames 1..5 (3)" in capsys.readouterr().out
    for stem in ("normal", "albedo", "distance", "material", "hit"):
        assert sequence(out, stem) == [1, 3, 5]
    assert sequence(out, "passes", ".exr") == [1, 3, 5], "one multilayer EXR per frame"
    summary = json.loads((out / "render.json").read_text())
    assert [f["frame"] for f in summary["frames"]] == [1, 3, 5]
    assert all(f["hit_pixels"] > 0 for f in summary["frames"]) and "camera" in summary["view"]

    single = tmp_path / "single"
    assert cli.main(["render", *scene, "--frame", "3", *SIZE, "--out", str(single)]) == 0
    assert np.array_equal(image_pixels(single / "normal.png"),
                          image_pixels(out / "normal.0003.png"))
    # the sequence's distance previews share the first frame's scale; a single frame's own
    first = tmp_path / "first"
    assert cli.main(["render", *scene, "--frame", "1", *SIZE, "--out", str(first)]) == 0
    assert json.loads((first / "render.json").read_text())["distance_preview_range"] == \
        summary["distance_preview_range"]
    assert np.array_equal(image_pixels(first / "distance.png"),
                          image_pixels(out / "distance.0001.png"))
    assert (single / "passes.exr").read_bytes() == (out / "passes.0003.exr").read_bytes()
    assert not np.array_equal(image_pixels(out / "normal.0001.png"),
                              image_pixels(out / "normal.0005.png")), "it moves"
    assert cli.main(["render", *scene, "--frames", "3:1", "--out", str(tmp_path / "x")]) == 1
    assert "argument --frames: the frame range 3:1 ends before it starts" in \
        capsys.readouterr().err


@pytest.mark.slow
def test_render_animation_over_the_scene_range_or_the_objects(trained,  # noqa: F811
                                                              monkeypatch):
    """At the scene's output path, resolution and percentage; with the AO toggle on, every
    frame's EXR holds the AO pass (and no file of its own); then the object's own range and
    folder, size and the viewer's pass deciding nothing."""
    from blender_exr import pass_names

    blend, _ = trained
    obj = reopen(blend)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 2, 4
    render = scene.render
    render.filepath = "//renders/shot_"
    render.resolution_x, render.resolution_y, render.resolution_percentage = 40, 30, 50
    obj.vdnif.use_scene_size, obj.vdnif.pass_ao = True, True
    bpy.ops.vdnif.render_animation()
    folder = blend.parent / "renders"
    assert sequence(folder, "shot_normal") == [2, 3, 4]
    assert sequence(folder, "shot_passes", ".exr") == [2, 3, 4]
    assert sequence(folder, "shot_ao") == [2, 3, 4] and sequence(folder, "shot_shadow") == []
    assert image_pixels(folder / "shot_normal.0003.png").shape == (15, 20, 4)
    assert {"AO", "Depth"} <= pass_names(folder / "shot_passes.0003.exr")
    assert "Shadow" not in pass_names(folder / "shot_passes.0003.exr")
    assert not list(folder.glob("*ao*.exr")), "AO goes into the frame's EXR"
    ao = image_pixels(folder / "shot_ao.0003.png")
    assert 0 < ao[..., :3].mean() < 1

    obj.vdnif.use_scene_size, obj.vdnif.pass_ao = False, False
    obj.vdnif.frames_dir = "//frames/"
    obj.vdnif.use_scene_frames = False
    obj.vdnif.frame_start, obj.vdnif.frame_end, obj.vdnif.frame_step = 10, 18, 4
    scene.vdnif_viewer.pass_name = "ao"              # viewing AO casts nothing
    bpy.ops.vdnif.render_animation()
    folder, prefix = module("storage").frames_output(obj, scene)
    assert (folder, prefix) == (blend.parent / "frames", "")
    assert sequence(folder) == [10, 14, 18] and sequence(folder, "ao") == []
    assert image_pixels(folder / "normal.0014.png").shape == (24, 32, 4)   # the panel's
    assert not {"AO", "Shadow"} & pass_names(folder / "passes.0014.exr")
    scene.vdnif_viewer.pass_name = "normal"

    obj.vdnif.frame_start, obj.vdnif.frame_end, obj.vdnif.frame_step = 20, 40, 1
    render = module("operators.animation").VDNIF_OT_render_animation
    ui_jobs = module("vdnif_addon.blender.ui_jobs")
    frames = ui_jobs.render_frames

    def held(*args, progress, **options):      # Esc lands at frame 2 however fast it runs
        def hold(done, total):
            progress(done, total)
            while done == 2:
                time.sleep(0.01)
                progress(done, total)

        return frames(*args, progress=hold, **options)

    monkeypatch.setattr(ui_jobs, "render_frames", held)
    result, status, reports = modal_run(render, "Arm", lambda state: state.count >= 2)
    written = [frame for frame in sequence(folder) if frame >= 20]
    assert result == {"FINISHED"} and written == [20, 21], "cancelled after frame 2"
    assert "render cancelled after" in reports[0][1]
    assert any(re.search(r"render: \d+/21 frames, ETA \d+ s", text) for text in status)


def rendered_frame(obj, frame, width, height, secondary=None):
    """Render Animation's RenderResult of ``frame`` of the Arm through the scene's camera at
    the preview's size (with ``secondary``, its AO and shadow settings)."""
    capture = module("vdnif_addon.blender.capture_scene").capture
    captured = capture(obj, 12, obj.vdnif.pose_spec(1), deform_corners=False)
    neural = module("vdnif_addon.posed.render")
    model = neural.load_scene_model(module("storage").model_path(obj), captured)
    reader = module("vdnif_addon.blender.pose_reader").PoseReader(
        obj, captured, lambda: neural.camera_view(bpy.context.scene.camera, width, height))
    kept = []
    try:
        module("vdnif_addon.posed.animation").render_frames(
            reader, captured, model, [frame], width, height, each=lambda _, r: kept.append(r),
            secondary=None if secondary is None else (lambda _frame: secondary))
    finally:
        reader.close()
    return kept[0]


@pytest.mark.slow
def test_live_preview_drops_frames_while_one_renders(trained):  # noqa: F811
    """A scrub over several frames while a render runs leaves one frame waiting, the newest;
    the ones between are dropped, never rendered; the images show the newest frame."""
    blend, _ = trained
    obj = reopen(blend)
    scene = bpy.context.scene
    scene.frame_set(1)
    preview = module("operators.live_preview")
    obj.vdnif.live_preview = True               # renders the current frame at once
    session = preview._sessions["Arm"]
    assert session.frames.running == 1 and session.renderer is None
    preview.tick()
    assert session.renderer.busy
    for frame in (2, 3, 4, 5, 6):               # the scrub, while frame 1 renders
        scene.frame_set(frame)
    assert session.frames.running == 1 and session.frames.waiting == 6
    assert session.frames.dropped == 4
    with module("vdnif_addon.blender.poses").posed({"frame": 9.0}):
        pass                                     # a job posing the scene: not a request
    assert session.frames.waiting == 6
    while preview.tick() is not None:
        pass
    assert session.shown == [1, 6] and session.error == ""
    width, height = preview.preview_size(obj.vdnif)
    assert (width, height) == (8, 6)
    shown = bpy.data.images["VDNIF Preview Normal"]
    assert tuple(shown.size) == (width, height)
    pixels = np.empty(width * height * 4, np.float32)
    shown.pixels.foreach_get(pixels)

    expected = module("vdnif_addon.posed.preview").images(
        rendered_frame(obj, 6, width, height).predicted, height, width)
    assert np.allclose(pixels.reshape(height, width, 4)[::-1], expected["normal"], atol=1e-6)
    obj.vdnif.live_preview = False
    assert "Arm" not in preview._sessions


@pytest.mark.slow
def test_live_preview_casts_ao_and_shadow_while_a_toggle_is_on(trained):  # noqa: F811
    """With the AO pass toggle on, the preview renders the AO and shadow passes as well, the
    same as Render Animation's render of that frame with the object's AO settings and the
    scene's light; with both toggles off it casts none."""
    blend, _ = trained
    obj = reopen(blend)
    scene = bpy.context.scene
    scene.frame_set(3)
    for name in ("VDNIF Preview AO", "VDNIF Preview Shadow"):
        if name in bpy.data.images:
            bpy.data.images.remove(bpy.data.images[name])
    preview = module("operators.live_preview")
    obj.vdnif.pass_ao, obj.vdnif.ao_samples = True, 4
    try:
        obj.vdnif.live_preview = True
        while preview.tick() is not None:
            pass
        session = preview._sessions["Arm"]
        assert session.shown == [3] and session.error == ""
        width, height = preview.preview_size(obj.vdnif)
        shown = {}
        for name in ("AO", "Shadow", "Normal"):
            image = bpy.data.images[f"VDNIF Preview {name}"]
            assert tuple(image.size) == (width, height)
            pixels = np.empty(width * height * 4, np.float32)
            image.pixels.foreach_get(pixels)
            shown[name] = pixels.reshape(height, width, 4)[::-1]
        secondary = module("operators.passes").secondary_settings(bpy.context, obj)
        assert secondary is not None and secondary.samples == 4
    finally:
        obj.vdnif.live_preview = False

    rendered = rendered_frame(obj, 3, width, height, secondary)
    lit = rendered.secondary["predicted"]
    assert lit.hit.any(), "the preview's view sees the arm"
    expected = module("vdnif_addon.posed.preview").images(rendered.predicted, height, width,
                                                            lit)
    assert np.allclose(shown["AO"], expected["ao"], atol=1e-6)
    assert np.allclose(shown["Shadow"], expected["shadow"], atol=1e-6)
    assert np.allclose(shown["Normal"], expected["normal"], atol=1e-6)

    obj.vdnif.pass_ao = False                      # both toggles off: no rays cast
    assert module("operators.passes").secondary_settings(bpy.context, obj) is None


def test_latest_frame_rule(extension):
    frames = module("vdnif_addon.posed.preview").LatestFrame()
    assert frames.request(1) and not frames.request(2) and not frames.request(3)
    assert (frames.running, frames.waiting, frames.dropped) == (1, 3, 1)
    assert frames.finished() == 3 and frames.running == 3 and frames.waiting is None
    assert frames.finished() is None and frames.request(4)
