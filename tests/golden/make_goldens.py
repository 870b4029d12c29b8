"""Writes the golden files the regression tests compare against.

The dataset, its inputs and the references come from the numpy/torch pipeline that the
compiled kernels replaced; today's kernels reproduce them within the tolerances their tests
state, and the loss curve trains on that dataset, so they are kept as independent
references rather than regenerated. The loss curve, the model files and the rendered passes
are today's code's (``train``, ``train-model``, ``render``): a change that moves them on
purpose writes them again and says why in its commit. Run from the repository root with the
bpy module, naming the parts to write (default: all):

    python tests/golden/make_goldens.py [dataset] [train] [train-model] [render] [references]

- ``arm-dataset/``: the dataset shard of the arm demo scene (resolution 12, 3 random poses of
  seed 0, 256 rays per pose, surface fraction 0.6) and ``arm-inputs.npz``: each pose's deformed
  voxel corners and training rays, so the walk and the ground-truth casts can be replayed on
  the same input without Blender.
- ``arm-train.json``: the per-step total and task losses of the first 50 training steps of the
  proposed variant on that shard (table 2^12, batch 1024, seed 0, no validation split).
- ``arm-train.vdnif``: the weights after those 50 steps (``train-model`` writes it alone).
- ``arm-render.npz`` and ``arm-render-model.vdnif``: a model trained 1,000 steps (batch
  2048; enough that its hits cover most of the arm's pixels in the view) and the passes
  the renderer predicted with it, its encoder the torch twin of the kernel
  (``tests/oracles/encoding_torch.py``, as ``test_render`` replays it), for the first
  evaluation pose (its deformed voxel corners and its 32x24 orbit rays are stored beside
  them).
- ``arm-references.json``: ``references`` metrics on 2 evaluation poses at 32x24.
"""

import json
import pathlib
import sys

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[2]
HERE = pathlib.Path(__file__).resolve().parent
sys.path[:0] = [str(REPO), str(REPO / "tests")]

import bpy  # noqa: E402,F401  (before mathutils)
from oracles import encoding_torch  # noqa: E402

from vdnif_addon.blender.capture_scene import capture  # noqa: E402
from vdnif_addon.blender.poses import posed  # noqa: E402
from vdnif_addon.blender.scenes import demo_scene  # noqa: E402
from vdnif_addon.blender.steps import evaluation_poses  # noqa: E402
from vdnif_addon.geometry.attributes import sample_surface  # noqa: E402
from vdnif_addon.inference.neural_render import neural_passes  # noqa: E402
from vdnif_addon.pose_sets import DEVELOPMENT_POSES, PoseSpec  # noqa: E402
from vdnif_addon.posed.generate import generate_dataset, reference_run  # noqa: E402
from vdnif_addon.posed.geometry import PosedObject  # noqa: E402
from vdnif_addon.posed.render import load_scene_model, orbit_view  # noqa: E402
from vdnif_addon.tracing.rays import orbit_viewpoints, training_rays  # noqa: E402
from vdnif_addon.training import dataset  # noqa: E402
from vdnif_addon.training.fit import fit_model  # noqa: E402

RESOLUTION, POSES, RAYS, SEED, FRACTION = 12, 3, 256, 0, 0.6
SMALL = dict(log2_table_size=12, normal_log2_table_size=12, device="cpu", seed=0)


def dataset_golden(obj, captured):
    folder = HERE / "arm-dataset"
    generate_dataset(obj, captured, folder, RAYS, FRACTION, SEED, grazing_fraction=0.0)
    inputs = {}
    with PosedObject(obj, captured) as posed_object:
        for index, pose in enumerate(captured.poses):
            geometry = posed_object.geometry(pose)
            rng = np.random.default_rng([SEED, index])          # as generate_dataset does
            surface, _, _ = sample_surface(geometry.vertices, captured.mesh.triangles, RAYS,
                                           rng)
            origins, directions = training_rays(geometry.vertices.min(0),
                                                geometry.vertices.max(0), surface, RAYS,
                                                FRACTION, rng)
            with posed(pose):
                inputs[f"corners_{index}"] = posed_object.deformer.deformed()
            inputs[f"origins_{index}"] = origins
            inputs[f"directions_{index}"] = directions
    np.savez_compressed(HERE / "arm-inputs.npz", **inputs)
    return folder


def training_golden(folder, curve=True):
    losses = []
    fit_model(folder, "proposed", HERE / "arm-train.vdnif",
              dict(SMALL, steps=50, batch_size=1024, log_interval=1, val_fraction=0.0),
              progress=lambda record: losses.append(
                  {"step": record["step"], "total": record["total"],
                   "losses": record["losses"]}))
    if not curve:
        return
    (HERE / "arm-train.json").write_text(json.dumps(
        {"settings": dict(SMALL, steps=50, batch_size=1024, val_fraction=0.0,
                          variant="proposed"), "history": losses}, indent=1) + "\n")


def render_golden(obj, folder):
    model_path = HERE / "arm-render-model.vdnif"
    fit_model(folder, "proposed", model_path,
              dict(SMALL, steps=1000, batch_size=2048, val_fraction=0.0))
    evaluated = evaluation_poses(obj, RESOLUTION, PoseSpec(count=2, seed=SEED),
                                 pose_set=DEVELOPMENT_POSES)
    model = load_scene_model(model_path, evaluated, "cpu")
    model.network.encoder = encoding_torch.from_product(model.network.encoder)
    with PosedObject(obj, evaluated) as posed_object:
        geometry = posed_object.geometry(evaluated.poses[0])
        with posed(evaluated.poses[0]):
            corners = posed_object.deformer.deformed()
        origins, directions = orbit_view(geometry, orbit_viewpoints(2)[0], 32, 24)
        passes, _ = neural_passes(model.network, model.grid, model.albedo_table,
                                  geometry.cells, origins, directions, "cpu")
        np.savez_compressed(HERE / "arm-render.npz", corners=corners,
                            origins=origins, directions=directions, hit=passes.hit,
                            distance=passes.distance, normal=passes.normal,
                            albedo=passes.albedo, material=passes.material)


def references_golden(obj):
    evaluated = evaluation_poses(obj, RESOLUTION, PoseSpec(count=2, seed=SEED),
                                 pose_set=DEVELOPMENT_POSES)
    report = reference_run(obj, evaluated, 32, 24)
    keep = {key: report[key] for key in ("object", "mode", "resolution", "poses", "width",
                                         "height", "embedded_vs_true", "per_pose",
                                         "segments_per_ray")}
    (HERE / "arm-references.json").write_text(json.dumps(keep, indent=1) + "\n")


PARTS = ("dataset", "train", "train-model", "render", "references")


def main(parts):
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise SystemExit(f"unknown parts {sorted(unknown)}: name some of {', '.join(PARTS)}")
    obj = demo_scene("arm")
    folder = HERE / "arm-dataset"
    if "dataset" in parts:
        captured = capture(obj, RESOLUTION, PoseSpec(count=POSES, seed=SEED),
                           deform_corners=False)
        dataset_golden(obj, captured)
    if "train" in parts or "train-model" in parts:
        training_golden(folder, curve="train" in parts)
    if "render" in parts:
        render_golden(obj, folder)
    if "references" in parts:
        references_golden(obj)
    assert dataset.read_dataset(folder)[0].segments > 0


if __name__ == "__main__":
    main(sys.argv[1:] or PARTS)
