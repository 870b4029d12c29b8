"""The side-by-side comparison on a tiny scene: every figure present, positive and finite,
and the tables written from it."""

import math

import pytest


@pytest.fixture(scope="module")
def tiny_result(extension):
    import importlib

    core = lambda name: importlib.import_module(f"{extension.__name__}.vdnif_addon.{name}")  # noqa: E731
    side = core("blender.side_by_side")
    obj = side.load_side_by_side_scene("lattice")
    poses = core("blender.poses")
    captured = core("blender.capture").capture(
        obj, 8, poses.evaluation_spec(poses.PoseSpec(count=2)), deform_corners=False)
    return side, side.compare_paths(obj, captured, None, 16, 16, repeats=1)


def test_compare_paths_times_both_paths(tiny_result):
    side, result = tiny_result
    assert result["repeats"] == 1 and result["poses"] == 2 and result["rays"] == 256
    assert len(result["runs"]) == 1 and len(result["runs"][0]["poses"]) == 2
    timings = [v for run in result["runs"] for record in run["poses"] + run["rest"]
               for k, v in record.items() if k.endswith("_s")]
    assert len(timings) == 2 * 10 + 2 * 3       # per pose and per rest view
    assert all(math.isfinite(t) and t > 0 for t in timings)
    assert set(result["ratios"]) == set(side.RATIOS)
    assert all(math.isfinite(r) and r > 0 for r in result["ratios"].values())
    assert result["segments_match"]                        # DDA walks the same cells
    assert not result["network"]["trained"]
    sizes = result["bytes"]
    assert sizes["model"] > 0 and sizes["mesh_and_bvh"] == sizes["mesh"] + sizes["bvh_estimate"]


def test_markdown_has_every_ratio(tiny_result):
    side, result = tiny_result
    text = side.side_by_side_markdown([result, result])
    for label, _ in side.RATIO_ROWS + side.TIME_ROWS:
        assert label in text
    assert text.count("Suzanne (3,936 triangles)") == 8    # 2 columns x 4 tables


def test_bad_settings_are_one_line(tiny_result, extension):
    import importlib

    side, _ = tiny_result
    errors = importlib.import_module(f"{extension.__name__}.vdnif_addon.errors")
    with pytest.raises(errors.VDNIFError, match="unknown scene 'teapot'"):
        side.load_side_by_side_scene("teapot")
