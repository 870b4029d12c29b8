"""Evaluate with the secondary rays reports the shaded image on a small trained model (the
golden arm model at resolution 12): its PSNR, visible-step share and the shadow rates split
at the terminator band, counted again here from the views it returns."""

import pathlib

import numpy as np
import pytest

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"
WIDTH, HEIGHT, POSES = 24, 16, 2


def srgb_code(linear):
    """The sRGB standard's encoding of linear values as 8-bit codes."""
    v = np.clip(linear, 0.0, 1.0)
    return np.round(255 * np.where(v <= 0.0031308, 12.92 * v,
                                   1.055 * v ** (1 / 2.4) - 0.055)).astype(int)


@pytest.fixture(scope="module")
def evaluated(extension):
    import importlib

    def core(name):
        return importlib.import_module(f"bl_ext.dev.vdnif.vdnif_addon.{name}")

    path = GOLDEN / "arm-render-model.vdnif"
    metadata = core("model.model_file").load_model(path)[1]
    obj = core("blender.scenes").demo_scene("arm")
    spec = core("pose_sets").PoseSpec(count=POSES)
    captured = core("blender.steps").model_capture(obj, metadata, spec, evaluation=True,
                                                   count=POSES)
    settings = core("inference.secondary").SecondarySettings(samples=4)
    report, views = core("blender.steps").evaluate_file(obj, captured, path, WIDTH, HEIGHT,
                                                         "cpu", secondary=settings)
    return report, views, core


def test_evaluate_reports_the_shaded_image_and_the_split_shadow_rates(evaluated):
    report, views, core = evaluated
    band = core("settings").TERMINATOR_BAND
    assert report["secondary"]["terminator_band"] == band
    world = np.array(core("inference.shading").BLENDER_WORLD)
    for reference in ("true", "embedded"):
        metrics = report[f"vs_{reference}"]
        assert metrics["shaded_pixels"] == POSES * WIDTH * HEIGHT
        predicted = np.concatenate([v["shaded"]["predicted"] for v in views])
        shaded = np.concatenate([v["shaded"][reference] for v in views])
        steps = np.abs(srgb_code(predicted) - srgb_code(shaded)).max(1)
        assert metrics["shaded_visible_rate"] == pytest.approx((steps > 2).mean())
        assert 0 < metrics["shaded_visible_rate"] < 0.5, "a trained model, not a blank"
        assert 10 < metrics["shaded_psnr"] < 100
        hit = np.concatenate([v[reference].hit for v in views])
        both = hit & np.concatenate([v["predicted"].hit for v in views])
        cosine = np.concatenate([v["cosines"][reference] for v in views])
        inside = both & (np.abs(np.nan_to_num(cosine, nan=9.0)) < band)
        assert metrics["shadow_rays_terminator"] == inside.sum() > 0
        assert metrics["shadow_rays_cast"] == (both & ~inside).sum()
        assert metrics["shadow_rays_terminator"] + metrics["shadow_rays_cast"] == (
            metrics["secondary_rays"])
        # each reference is shaded from its own passes: a miss shows the world, a shadowed
        # hit the albedo under the world times its AO
        np.testing.assert_allclose(shaded[~hit], np.broadcast_to(world, shaded[~hit].shape),
                                   rtol=1e-6)
        secondary = core("passes").SecondaryPasses.concatenate(
            [v["secondary"][reference] for v in views])
        albedo = np.concatenate([v[reference].albedo for v in views])
        dark = hit & ~secondary.lit
        assert dark.any()
        np.testing.assert_allclose(shaded[dark], albedo[dark] * world * secondary.ao[dark, None],
                                   rtol=1e-5, atol=1e-7)
    for row in report["per_pose"]:
        assert {"shaded_psnr", "shaded_visible_rate", "shadow_false_lit_rate_cast",
                "shadow_false_shadow_rate_terminator"} <= set(row["vs_true"])
