"""The metrics of DESIGN section 10 on hand-made images whose answers are counted by hand:
the hit-mask rates, n/a where there is nothing to divide by, the common pixel set of compared
models, the speed rule and the presets derived only from models that predict hits."""

import numpy as np
import pytest

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry.restmesh import Albedo, RestMesh
from vdnif_addon.inference.evaluation import (
    compare_both,
    compare_common,
    metric_heads,
    speed_figures,
)
from vdnif_addon.inference.metrics import (
    CLEAN_RATE,
    SPEED_MIN_HIT_IOU,
    Passes,
    common_pixels,
    compare,
    speed_withheld,
    verdict,
)
from vdnif_addon.presets import SETTINGS
from vdnif_addon.studies.pareto import pick_presets

UP = np.array([0.0, 0.0, 1.0])


def image(rows, distance=1.0, material=0):
    """Passes from a picture: '#' a hit, '.' a miss; one ray per character."""
    hit = np.array([c == "#" for row in rows for c in row])
    n = len(hit)
    return Passes(hit=hit, distance=np.full(n, float(distance)), normal=np.tile(UP, (n, 1)),
                  albedo=np.full((n, 3), 0.5, np.float32),
                  material=np.full(n, material, np.int32))


REFERENCE = ["....",
             ".##.",
             ".##.",
             "...."]          # 4 hits
PREDICTED = ["....",
             ".#..",          # one hole
             ".###",          # one extra
             "#..."]          # another extra


def test_rates_count_holes_and_extras_over_the_reference_hits():
    m = compare(image(PREDICTED), image(REFERENCE), object_size=2.0)
    assert m["false_negative_rate"] == pytest.approx(1 / 4)
    assert m["false_positive_rate"] == pytest.approx(2 / 4)
    assert m["hit_iou"] == pytest.approx(3 / 6)          # 3 shared of 6 hit anywhere
    assert m["compared_rays"] == 3


def test_nothing_hit_gives_no_rates_and_no_iou():
    empty = ["...", "..."]
    m = compare(image(empty), image(empty), object_size=1.0, heads={"material": True},
                voxel_size=0.1)
    for key in ("hit_iou", "false_negative_rate", "false_positive_rate", "distance_mae",
                "distance_mae_voxels", "normal_error_deg", "material_accuracy"):
        assert m[key] is None, key
    assert m["compared_rays"] == 0
    # the prediction hits where the reference has nothing: no share of nothing, IoU 0
    m = compare(image(["#..", "..."]), image(empty), object_size=1.0)
    assert m["false_negative_rate"] is None and m["false_positive_rate"] is None
    assert m["hit_iou"] == 0.0


def test_everything_hit_is_perfect_and_errors_come_in_both_units():
    full = ["###", "###"]
    m = compare(image(full, distance=1.3), image(full, distance=1.0), object_size=3.0,
                voxel_size=0.1)
    assert m["hit_iou"] == 1.0
    assert m["false_negative_rate"] == 0.0 and m["false_positive_rate"] == 0.0
    assert m["distance_mae"] == pytest.approx(0.3 / 3.0)
    assert m["distance_mae_voxels"] == pytest.approx(0.3 / 0.1)
    assert m["normal_error_deg"] == pytest.approx(0.0)
    assert "distance_mae_voxels" not in compare(image(full), image(full), 1.0)


def test_common_pixel_set_is_the_intersection_over_compared_models():
    """Model A predicts few, easy hits (exact there); model B predicts every reference hit
    but is off by 0.2 where A is silent. On their own pixels A looks perfect; on the common
    set both are measured on the same pixels only."""
    reference = image(["####", "####"])
    a = image(["##..", "##.."])
    b = image(["####", "####"])
    b.distance[[2, 3, 6, 7]] += 0.2
    mesh = one_material_mesh()
    runs = [{"predicted": p, "true": reference, "embedded": reference} for p in (a, b)]
    own = [compare_both(p, reference, reference, mesh) for p in (a, b)]
    assert own[0]["vs_true"]["distance_mae"] == 0 and own[1]["vs_true"]["distance_mae"] > 0
    common = compare_common(runs, mesh, [0.5, 0.25])
    pixels = common_pixels([(a, reference), (b, reference)])
    assert pixels.tolist() == [True, True, False, False] * 2
    for metrics, h in zip(common, (0.5, 0.25)):
        for reference_name in ("vs_true", "vs_embedded"):
            m = metrics[reference_name]
            assert m["compared_rays"] == 4
            assert m["distance_mae"] == 0 and m["distance_mae_voxels"] == 0
    # the hit-mask metrics still count every pixel
    assert common[0]["vs_true"]["hit_iou"] == pytest.approx(0.5)
    assert common[0]["vs_true"]["false_negative_rate"] == pytest.approx(0.5)
    assert common[1]["vs_true"]["hit_iou"] == 1.0


def test_models_seen_through_other_rays_are_not_compared():
    reference = image(["##", ".."])
    other = image(["#.", ".#"])
    runs = [{"predicted": reference, "true": t, "embedded": t} for t in (reference, other)]
    with pytest.raises(VDNIFError, match="different rays or poses"):
        compare_common(runs, one_material_mesh(), [1.0, 1.0])


def one_material_mesh(albedo=None, material_index=None, slots=None):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    triangles = np.array([[0, 1, 2], [0, 1, 3]], np.int32)
    return RestMesh(name="Tri", vertices=vertices, triangles=triangles,
                    corner_normals=np.zeros((2, 3, 3), np.float32),
                    material_index=np.zeros(2, np.int32) if material_index is None
                    else material_index,
                    albedo=albedo or [Albedo("constant", np.full(3, 0.5, np.float32))],
                    used_slots=slots)


def test_albedo_psnr_and_material_accuracy_only_where_something_is_predicted():
    red, blue = (Albedo("constant", np.array(c, np.float32)) for c in ((1, 0, 0), (0, 0, 1)))
    texture = Albedo("texture", np.zeros(3, np.float32), texture=np.zeros((2, 2, 3),
                                                                          np.float32))
    assert metric_heads(one_material_mesh()) == {"albedo_psnr": False, "material": False}
    assert metric_heads(one_material_mesh([texture])) == {"albedo_psnr": True,
                                                          "material": False}
    two = one_material_mesh([red, blue], np.array([0, 1], np.int32))
    assert metric_heads(two) == {"albedo_psnr": True, "material": True}
    full = image(["##"])
    single = compare_both(full, full, full, one_material_mesh())["vs_true"]
    assert "albedo_psnr" not in single and "material_accuracy" not in single
    several = compare_both(full, full, full, two)["vs_true"]
    assert several["albedo_psnr"] == 100.0 and several["material_accuracy"] == 1.0


def test_material_pass_shows_the_slot_the_user_knows():
    passes = image(["#.#"], material=1)
    passes.material[0] = 0
    shown = passes.with_slots(np.array([1, 3]))
    assert shown.material.tolist() == [1, 0, 3]             # a miss shows 0
    assert one_material_mesh(slots=np.array([2])).material_slots.tolist() == [2]
    assert one_material_mesh().heads()["material_slots"] == [0]


def test_speed_only_from_models_that_predict_hits():
    assert speed_withheld(SPEED_MIN_HIT_IOU) is None and speed_withheld(1.0) is None
    assert speed_withheld(0.62) == ("hit IoU 0.620 against the true reference is below 0.9: "
                                    "the model does not predict hits")
    assert "hits anything" in speed_withheld(None)
    timings = {"render_rays_per_s": 1e5, "render_segments_per_s": 3e5,
               "network_fraction": 0.7, "prepare_pose_s": 0.01}
    kept, reason = speed_figures(timings, {"hit_iou": 0.95})
    assert kept == timings and reason is None
    withheld, reason = speed_figures(timings, {"hit_iou": 0.5})
    assert reason == speed_withheld(0.5)
    assert withheld == dict(timings, render_rays_per_s=None, render_segments_per_s=None,
                            network_fraction=None)


def point(error, speed, resolution, hit_iou=0.95):
    return dict(dict.fromkeys(SETTINGS, 1), resolution=resolution, error=error,
                render_rays_per_s=speed, vs_true_hit_iou=hit_iou)


def test_presets_come_only_from_points_that_predict_hits():
    """The fastest and the most accurate points have a hit IoU below 0.9: neither becomes a
    preset, though both would be on the front."""
    points = [point(0.08, 1000.0, 16), point(0.04, 900.0, 24), point(0.02, 100.0, 48),
              point(0.09, 5000.0, 8, hit_iou=0.5), point(0.001, 800.0, 64, hit_iou=0.89)]
    presets = pick_presets(points)
    assert [presets[name]["resolution"] for name in ("fast", "balanced", "accurate")] == [
        16, 24, 48]
    with pytest.raises(VDNIFError, match="no sweep point has both"):
        pick_presets([point(0.01, 10.0, 8, hit_iou=0.3)])


def test_summary_lines_give_units_and_grammar():
    from vdnif_addon.text import article, metrics_line

    assert [article(w) for w in ("armature", "empty", "mesh", "Lattice")] == [
        "an armature", "an empty", "a mesh", "a Lattice"]
    line = metrics_line({"distance_mae": 0.001, "distance_mae_voxels": 0.03,
                         "normal_error_deg": 2.5, "hit_iou": 0.99, "false_negative_rate": 0.001,
                         "false_positive_rate": 0.002, "albedo_psnr": 8.359,
                         "material_accuracy": 0.995})
    assert "albedo PSNR 8.359 dB" in line and "material accuracy 99.5 %" in line
    assert "albedo PSNR n/a, material accuracy n/a" in metrics_line(
        {"distance_mae": None, "normal_error_deg": None, "hit_iou": None})


def test_verdict_is_clean_only_when_holes_and_extras_are_each_within_the_rate():
    assert verdict({"false_negative_rate": CLEAN_RATE, "false_positive_rate": 0.0}) == "clean"
    assert verdict({"false_negative_rate": 0.0, "false_positive_rate": 0.0123}) == (
        "speckled: 0 % holes, 1.2 % extras")
    assert verdict({"false_negative_rate": 0.0051, "false_positive_rate": CLEAN_RATE}) == (
        "speckled: 0.51 % holes, 0.5 % extras")
    assert verdict({"false_negative_rate": None, "false_positive_rate": None}).startswith("n/a")
