"""The AO and Shadow passes in the frame's multilayer EXR as their toggles ask, the render size
and output path taken from the scene unless the panel overrides them, one distance scale for
compared images and every frame of a sequence, the exact path's speed beside the network's,
and the demo's verdict, report and figures."""

import importlib
import json
import struct

import bpy
import numpy as np
import pytest
from blender_exr import pass_names, read_multilayer
from conftest import EXTENSION_MODULE
from test_compositor_output import HEIGHT, WIDTH, random_passes


def module(name):
    return importlib.import_module(f"{EXTENSION_MODULE}.{name}")


def random_secondary(core, passes, rng):
    """SecondaryPasses of the rays of ``passes``: AO in quarters (4 rays), random lit."""
    rays = len(passes.hit)
    hit = passes.hit
    return core("passes").SecondaryPasses(
        hit=hit, ao=np.where(hit, rng.integers(0, 5, rays) / 4, 0).astype(np.float32),
        lit=hit & (rng.random(rays) < 0.5), facing=hit.copy())


@pytest.mark.parametrize("names", [("ao", "shadow"), ("shadow",), ()])
def test_the_toggled_secondary_passes_go_into_the_frames_exr(empty_scene, core, tmp_path,
                                                             names):
    rng = np.random.default_rng(7)
    passes = random_passes(core, rng)
    secondary = random_secondary(core, passes, rng)
    written = core("blender.steps").write_passes(tmp_path, passes, HEIGHT, WIDTH, frame=3,
                                                secondary=secondary if names else None,
                                                secondary_names=names)
    titles = {"ao": "AO", "shadow": "Shadow"}
    assert sorted(path.name for path in written) == sorted(
        [f"{name}.0003.png" for name in ("hit", "normal", "albedo", "distance", "material",
                                         *names)] + ["passes.0003.exr"])
    exr = tmp_path / "passes.0003.exr"
    assert pass_names(exr) == {"Combined", "Depth", "Normal", "DiffCol", "IndexMA",
                               *(titles[name] for name in names)}
    if not names:
        return
    _, read = read_multilayer(exr, WIDTH, HEIGHT)
    expected = {"ao": np.where(passes.hit, secondary.ao, 0),
                "shadow": np.where(passes.hit, secondary.lit, 0)}
    for name in names:
        image = read[titles[name]]
        for channel in range(3):                       # grey: the value in R, G and B
            np.testing.assert_allclose(image[..., channel],
                                       expected[name].reshape(HEIGHT, WIDTH), atol=1e-6)


def test_compared_images_and_every_frame_share_one_distance_scale(empty_scene, core, tmp_path):
    """Two frames through one DistanceScale: a pixel at the same distance has the same grey
    in both, though the second frame's other pixels lie much farther (each image scaled on
    its own would brighten it)."""
    steps = core("blender.steps")
    rng = np.random.default_rng(2)
    first = random_passes(core, rng)
    first.hit[:] = True
    second = core("passes").Passes(hit=first.hit.copy(), distance=first.distance + 50,
                                   normal=first.normal, albedo=first.albedo,
                                   material=first.material)
    second.distance[0] = first.distance[0]
    scale = steps.DistanceScale()
    for frame, passes in ((1, first), (2, second)):
        steps.write_passes(tmp_path, passes, HEIGHT, WIDTH, frame=frame, scale=scale)
    near, far = first.distance.min(), first.distance.max()
    pad = 0.1 * (far - near)
    assert scale.near_far == pytest.approx((near - pad, far + pad))
    grey = []
    for frame in (1, 2):
        image = bpy.data.images.load(str(tmp_path / f"distance.000{frame}.png"))
        pixels = np.empty(HEIGHT * WIDTH * 4, np.float32)
        image.pixels.foreach_get(pixels)
        grey.append(pixels.reshape(HEIGHT, WIDTH, 4)[::-1, :, 0].ravel())
    assert grey[0][0] == grey[1][0]
    assert (grey[1][1:] < 0.16).all(), "farther than the first frame's scale: clipped dark"
    fresh = steps.DistanceScale()
    assert fresh(core("passes").Passes.empty(4)) == (0.0, 1.0) and fresh.near_far is None


def test_the_live_preview_keeps_one_distance_scale_over_its_frames(core):
    """The preview's distance image of a later frame is on the first frame's scale: the
    same distance, the same grey, though the rest of the frame moved far away."""
    rng = np.random.default_rng(5)
    first = random_passes(core, rng)
    first.hit[:] = True
    second = core("passes").Passes(hit=first.hit.copy(), distance=first.distance * 10,
                                   normal=first.normal, albedo=first.albedo,
                                   material=first.material)
    second.distance[0] = first.distance[0]
    preview = core("posed.preview")
    scale = core("inference.evaluation").DistanceScale()
    kept = [preview.images(p, HEIGHT, WIDTH, scale=scale)["distance"] for p in (first, second)]
    alone = preview.images(second, HEIGHT, WIDTH)["distance"]
    assert kept[0][0, 0, 0] == kept[1][0, 0, 0] != alone[0, 0, 0]


def mesh_object():
    mesh = bpy.data.meshes.new("M")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("M", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def test_render_size_is_the_scenes_output_unless_the_panel_overrides_it(empty_scene):
    obj = mesh_object()
    render = empty_scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = 1001, 500, 30
    viewer, settings = module("viewer"), obj.vdnif
    assert settings.use_scene_size, "the scene's output size by default"
    assert viewer.render_size(empty_scene, settings) == (300, 150)    # Blender truncates
    settings.preview_percent = 10
    assert module("operators.live_preview").preview_size(settings, empty_scene) == (30, 15)
    settings.use_scene_size = False
    settings.image_width, settings.image_height = 64, 48
    assert viewer.render_size(empty_scene, settings) == (64, 48)


def test_render_animation_writes_to_the_scenes_output_path(empty_scene, tmp_path):
    obj = mesh_object()
    storage = module("storage")
    render = empty_scene.render
    render.filepath = str(tmp_path / "renders") + "/"
    assert storage.frames_output(obj, empty_scene) == (tmp_path / "renders", "")
    render.filepath = str(tmp_path / "renders" / "shot_")
    assert storage.frames_output(obj, empty_scene) == (tmp_path / "renders", "shot_")
    (tmp_path / "dir").mkdir()
    render.filepath = str(tmp_path / "dir")              # an existing folder: a folder
    assert storage.frames_output(obj, empty_scene) == (tmp_path / "dir", "")
    obj.vdnif.frames_dir = str(tmp_path / "chosen")      # the panel's folder overrides it
    assert storage.frames_output(obj, empty_scene) == (tmp_path / "chosen", "")
    obj.vdnif.frames_dir, render.filepath = "", "//shots/a_"   # relative to unsaved .blend
    assert storage.frames_output(obj, empty_scene) == (
        storage.user_folder("frames", storage.slug(obj)) / "shots", "a_")
    obj.vdnif.frames_dir, render.filepath = "", ""       # no output path: the old fallback
    assert storage.frames_output(obj, empty_scene) == (
        storage.user_folder("frames", storage.slug(obj)), "")       # unsaved .blend


def report(holes, extras, exact=2.5e6, speed=4.0e5):
    """An evaluation report with the fields the report writers read."""
    metrics = {"distance_mae": 0.001, "distance_mae_voxels": 0.03, "normal_error_deg": 2.0,
               "hit_iou": 0.99, "false_negative_rate": holes, "false_positive_rate": extras}
    return {"object": "Spot", "variant": "proposed", "mode": "deformed", "resolution": 32,
            "poses": 8, "unseen_poses": True, "width": 64, "height": 48, "train_poses": 32,
            "dataset_rays": 100, "dataset_segments": 200, "vs_true": metrics,
            "vs_embedded": dict(metrics), "speed_withheld": None, "model_bytes": 1000,
            "timings": {"render_rays_per_s": speed, "exact_rays_per_s": exact,
                        "prepare_pose_s": 0.01, "train_s": 10.0, "train_steps": 100,
                        "train_samples_per_s": 1e4}}


def test_the_demo_report_judges_by_the_clean_pass_rule(core):
    report_module = core("studies.report")
    clean = report_module.demo_markdown(report(0.004, 0.005), "python batch.py -- demo")
    assert "**clean** (holes 0.4 %, extras 0.5 %)" in clean
    assert "on the 8 unseen poses" in clean and "Goal" not in clean and "paper" not in clean
    speckled = report_module.verdict_line(report(0.004, 0.0051))
    assert "**speckled: 0.4 % holes, 0.51 % extras**" in speckled
    assert "| exact path (Warp's BVH of the deformed mesh, refit per pose), same rays | " \
           "2,500,000 rays/s |" in clean
    assert "docs/performance.md" in clean and "Embree" in clean
    assert "400,000 rays/s" in clean and "speed-accuracy.png" in clean


def test_evaluate_prints_the_exact_paths_speed_beside_the_networks(core, capsys):
    data = dict(report(0.0, 0.0, exact=1234567.0, speed=234567.0), precision="float32")
    core("cli.options").print_evaluation(data)
    printed = capsys.readouterr().out
    assert ("speed on the same rays: network 234,567 rays/s; exact path (Warp's BVH of the "
            "deformed mesh, refit per pose) 1,234,567 rays/s") in printed
    assert "Embree" in printed and "docs/performance.md" in printed


def png_size(path):
    return struct.unpack(">II", path.read_bytes()[16:24])      # PNG's IHDR


def test_demo_figures_scale_their_error_bars_to_the_data(core, tmp_path):
    """The figures are written for a view; an error bar ends at the 99th percentile of the
    errors where both hit, so an error of 0.001 is not drawn dark on a scale of 0.05."""
    figures = core("studies.demo_figures")
    rng = np.random.default_rng(3)
    true = random_passes(core, rng)
    predicted = core("passes").Passes(
        hit=true.hit.copy(), distance=true.distance + rng.uniform(0, 0.001, len(true.hit)),
        normal=true.normal, albedo=true.albedo, material=true.material)
    predicted.hit[0] = not true.hit[0]
    both = true.hit & predicted.hit
    errors = np.abs(predicted.distance - true.distance)[both]
    assert figures._error_scale(errors) == pytest.approx(np.percentile(errors, 99))
    assert figures._error_scale(np.zeros(3)) > 0
    view = {"predicted": predicted, "true": true, "embedded": true,
            "secondary": {name: random_secondary(core, passes, rng)
                          for name, passes in (("true", true), ("predicted", predicted))}}
    paths = figures.demo_figures(tmp_path, report(0.0, 0.0), view, HEIGHT, WIDTH, 1.0)
    assert set(paths) == {"figure_vs_true", "figure_vs_embedded", "figure_secondary_vs_true",
                          "speed_accuracy"}
    for path in paths.values():
        width, height = png_size(path)
        assert width > 500 and height > 300, path


def test_the_speed_accuracy_plot_marks_the_shipped_presets(core):
    presets = core("presets").load_presets()
    points = core("studies.demo_figures").sweep_points()
    for name in presets:      # each preset offered (none dropped) is a point of the sweep
        measured = presets[name]["measured"]
        assert any(speed == pytest.approx(measured["render_rays_per_s"]) and error ==
                   pytest.approx(measured[core("presets").PRESET_ERROR])
                   for speed, error in points), name
    sweep = json.loads(core("studies.demo_figures").SWEEP.read_text())
    assert len(points) == sum(1 for p in sweep if p["render_rays_per_s"])
