"""tools/wrong_surface.py: the split of the both-hit pixels on hand-made passes, and bad
input ending in one error line."""

import pathlib

import numpy as np
import pytest
from tool_errors import load_tool, one_error_line

from vdnif_addon.passes import Passes

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "wrong_surface.py"


def _passes(hit, distance, albedo):
    rays = len(hit)
    normal = np.tile([0.0, 0.0, 1.0], (rays, 1))
    return Passes(np.array(hit), np.array(distance, float), normal,
                  np.array(albedo, np.float32), np.zeros(rays, np.int32))


def test_a_hit_on_another_surface_is_split_from_the_rest():
    # Rays: both hit 0.01 apart; both hit 2.0 apart (another surface); a hole; an extra.
    reference = _passes([True, True, True, False], [1.0, 1.0, 1.0, 0.0],
                        [[0.5, 0.5, 0.5]] * 4)
    predicted = _passes([True, True, False, True], [1.01, 3.0, 0.0, 1.0],
                        [[0.6, 0.5, 0.5], [0.0, 0.0, 0.0], [0.5] * 3, [0.5] * 3])
    split = load_tool(TOOL).wrong_surface(predicted, reference, voxel_size=0.1, voxels=0.5,
                                  object_size=2.0, heads={"albedo_psnr": True})
    assert (split["pixels"], split["wrong"]) == (2, 1)
    assert split["distance_share"] == pytest.approx(2.0 / 2.01)
    assert split["albedo_share"] == pytest.approx(0.75 / 0.76)
    assert split["all"]["distance_mae"] == pytest.approx(1.005 / 2.0)
    assert split["rest"]["distance_mae"] == pytest.approx(0.01 / 2.0)
    assert split["rest"]["albedo_psnr"] == pytest.approx(-10 * np.log10(0.01 / 3), rel=1e-5)
    # The hole and the extra count in the hit-mask rates alone, in both splits.
    assert split["rest"]["false_negative_rate"] == pytest.approx(1 / 3)


def test_without_an_albedo_metric_there_is_no_albedo_share():
    reference = _passes([True], [1.0], [[0.5] * 3])
    predicted = _passes([True], [1.0], [[0.1] * 3])
    split = load_tool(TOOL).wrong_surface(predicted, reference, 0.1, 0.5, 1.0,
                                          {"albedo_psnr": False})
    assert split["albedo_share"] is None and split["distance_share"] is None
    assert split["wrong"] == 0


@pytest.mark.parametrize("arguments, message", [
    (["--voxels", "0"], "--voxels must be"),
    (["--voxels", "nan"], "--voxels must be"),
    (["--scene", "nope"], "argument --scene: invalid choice: 'nope'"),
    (["--scene", "spot"], "the following arguments are required: --model"),
])
def test_bad_input_ends_in_one_error_line(arguments, message):
    assert message in one_error_line(TOOL, arguments)
