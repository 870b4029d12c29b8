"""The models of the side-by-side scenes: a scene without a model on the command line gets one
trained by the recipe (``settings.RECIPE``: its resolution for the mesh, poses, rays per pose
and steps), kept in a folder and used again by the next run."""

import pathlib
import sys
import tempfile

from ..blender.capture_scene import capture
from ..blender.resolution import recipe_resolution
from ..blender.steps import train_variant
from ..model.variants import choose_variant
from ..pose_sets import PoseSpec
from ..settings import RECIPE
from .side_by_side_scenes import load_side_by_side_scene

SIZES = {   # full: the recipe; quick: a tiny training, for tests (its models predict no hits)
    "full": dict(resolution=None, poses=RECIPE.poses, rays_per_pose=RECIPE.rays_per_pose,
                 overrides={}),
    "quick": dict(resolution=8, poses=2, rays_per_pose=64,
                  overrides=dict(steps=20, batch_size=256, log2_table_size=10)),
}


def model_file(folder, scene):
    """Where the model trained for ``scene`` lives in ``folder``."""
    return pathlib.Path(folder) / f"{scene}.vdnif"


def recipe_model(scene, folder, seed=0, device="auto", quick=False, progress=None):
    """The model of side-by-side scene ``scene`` in ``folder``, trained first (by the recipe,
    training poses of ``seed``) where the file is missing; returns its path."""
    path = model_file(folder, scene)
    if path.exists():
        print(f"side-by-side: '{scene}' uses the model {path} (trained before)",
              file=sys.stderr)
        return path
    size = SIZES["quick" if quick else "full"]
    obj = load_side_by_side_scene(scene)
    resolution = size["resolution"] or recipe_resolution(obj)
    captured = capture(obj, resolution, PoseSpec(count=size["poses"], seed=seed),
                       deform_corners=False)
    variant, _ = choose_variant(None, captured.mode == "static")
    path.parent.mkdir(parents=True, exist_ok=True)
    print(f"side-by-side: training {variant} on '{obj.name}' ({scene}) by the "
          f"{'quick size' if quick else 'recipe'} into {path}", file=sys.stderr)
    overrides = dict(size["overrides"], device=device, seed=seed)
    with tempfile.TemporaryDirectory(prefix="vdnif-data-") as scratch:
        train_variant(obj, captured, variant, scratch, size["rays_per_pose"], path, overrides,
                      seed, progress=progress)
    return path
