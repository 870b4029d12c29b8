"""One default recipe (``vdnif_addon/settings.py``) read by every place that has defaults."""

import dataclasses
import subprocess
import sys

import pytest

from vdnif_addon import settings
from vdnif_addon.cli import build_parser
from vdnif_addon.settings import RECIPE, TrainConfig


def test_settings_import_neither_torch_nor_bpy():
    code = ("import sys; import vdnif_addon.settings; "
            "print(any(name in sys.modules for name in ('torch', 'bpy', 'warp')))")
    printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True).stdout
    assert printed.strip() == "False"


def test_the_recipe_is_frozen_and_its_mix_adds_up():
    with pytest.raises(dataclasses.FrozenInstanceError):
        RECIPE.steps = 1
    assert 0 <= RECIPE.surface_fraction + RECIPE.grazing_fraction \
        + RECIPE.secondary_fraction <= 1


def test_training_config_and_commands_default_to_the_recipe():
    config = TrainConfig()
    assert (config.steps, config.batch_size) == (RECIPE.steps, RECIPE.batch_size)
    parser = build_parser()
    train = parser.parse_args(["train", "--scene", "arm"])
    # No resolution: the suggested one, resolved once the mesh is read (test_resolution.py).
    assert (train.resolution, train.poses, train.rays_per_pose, train.steps, train.batch) == (
        "auto", RECIPE.poses, RECIPE.rays_per_pose, RECIPE.steps, RECIPE.batch_size)
    data = parser.parse_args(["dataset", "--scene", "arm", "--out", "d"])
    assert (data.resolution, data.poses, data.rays_per_pose, data.surface_fraction,
            data.grazing_fraction, data.secondary_fraction) == (
        "auto", RECIPE.poses, RECIPE.rays_per_pose, RECIPE.surface_fraction,
        RECIPE.grazing_fraction, RECIPE.secondary_fraction)
    assert parser.parse_args(["demo"]).scene == settings.DEMO_SCENE == "spot"


@pytest.mark.parametrize("text, expected", [("auto", "auto"), ("recipe", "recipe"), ("24", 24)])
def test_resolution_takes_a_number_auto_or_recipe(text, expected):
    args = build_parser().parse_args(["capture", "--scene", "arm", "--resolution", text])
    assert args.resolution == expected
