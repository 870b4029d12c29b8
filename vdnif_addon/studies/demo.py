"""The main job: on an embedded demo scene, capture, dataset, train the proposed variant (the
static one where nothing deforms the scene), evaluate on unseen poses (the AO and shadow
passes too), write the passes, the figures and a short report."""

import pathlib
import shlex
import sys
import tempfile

import bpy

from ..blender.lights import scene_secondary
from ..blender.resolution import recipe_resolution
from ..blender.scenes import demo_scene
from ..blender.steps import (
    DistanceScale,
    evaluate_file,
    evaluation_poses,
    train_variant,
    training_capture,
    write_passes,
    write_training_plot,
)
from ..model.provenance import stamp
from ..model.variants import choose_variant
from ..output_rule import REPORT_FORMAT
from ..pose_sets import TEST_POSES, PoseSpec
from ..safe_io import write_json_atomic, write_text_atomic
from ..settings import RECIPE
from .demo_figures import demo_figures
from .report import demo_markdown

SIZES = {   # full: the main job, the default recipe at the resolution of the scene's mesh
    # (None); quick: tests
    "full": dict(resolution=None, poses=RECIPE.poses,
                 rays_per_pose=RECIPE.rays_per_pose, steps=RECIPE.steps, eval_poses=8,
                 width=256, height=256, overrides={}),
    # quick: with every task at weight 1 from the start (TrainConfig.weighting_start), half
    # these steps leave the arm's model short of the hits tests/cli/test_batch.py asks for.
    "quick": dict(resolution=16, poses=4, rays_per_pose=256, steps=600, eval_poses=2,
                  width=32, height=24, overrides=dict(log2_table_size=12, batch_size=2048)),
}


def run_demo(scene, out, quick=False, device="auto", steps=None, progress=None,
             stress=lambda obj, spec: spec):
    """Runs the demo into folder ``out`` and returns the report (also written as
    ``out/report.json`` and ``out/report.md`` with the figures of
    ``demo_figures.demo_figures`` and the first view's passes in ``out/passes``, AO and
    Shadow in its EXR; the light: the scene's first sun or point light, else the default
    direction).
    ``stress(obj, spec)`` may scale the scene and return the pose spec with an extreme pose
    (``extremes.apply_stress``)."""
    size = SIZES["quick" if quick else "full"]
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    obj = demo_scene(scene)
    spec = stress(obj, PoseSpec(count=size["poses"]))
    resolution = size["resolution"] or recipe_resolution(obj)
    captured = training_capture(obj, resolution, spec,
                                say=lambda line: print(f"demo: '{obj.name}': {line}",
                                                       file=sys.stderr))
    variant, note = choose_variant(None, captured.mode == "static")
    if note is not None:
        print(f"demo: '{obj.name}': {note}", file=sys.stderr)
    overrides = dict(size["overrides"], steps=size["steps"] if steps is None else steps,
                     device=device)
    model = out / f"{scene}-{variant}.vdnif"
    with tempfile.TemporaryDirectory(prefix="data-", dir=out) as folder:
        _, summary = train_variant(obj, captured, variant, folder, size["rays_per_pose"],
                                   model, overrides, progress=progress)
    evaluated = evaluation_poses(obj, resolution, spec, count=size["eval_poses"],
                                 pose_set=TEST_POSES, follow=captured.corners_follow)
    width, height = size["width"], size["height"]
    secondary = scene_secondary(bpy.context.scene, obj)
    report, views = evaluate_file(obj, evaluated, model, width, height, device,
                                  secondary=secondary)
    view = views[0]
    figures = demo_figures(out, report, view, height, width, captured.mesh.size)
    passes = write_passes(out / "passes", view["predicted"], height, width,
                          secondary=view.get("secondary", {}).get("predicted"),
                          scale=DistanceScale(), shaded=view.get("shaded", {}).get("predicted"))
    plot = write_training_plot(out / "training.png", summary["history"])
    report.update(train_poses=len(captured.poses), variant_note=note,
                  dataset_rays=summary["dataset"]["rays"],
                  dataset_segments=summary["dataset"]["segments"],
                  figures={name: str(path) for name, path in figures.items()},
                  passes=[str(path) for path in passes], report=str(out / "report.md"),
                  history=summary["history"], training_plot=str(plot))
    command = shlex.join(["python", "vdnif_addon/batch.py", "--",
                          *sys.argv[sys.argv.index("--") + 1:]] if "--" in sys.argv
                         else ["python", "vdnif_addon/batch.py", "--", "demo"])
    write_text_atomic(out / "report.md", demo_markdown(report, command), "markdown file",
                      "markdown")
    # the report holds the demo's training and render times: recorded with the machine
    write_json_atomic(out / "report.json", stamp({"format": REPORT_FORMAT, **report},
                                                 with_machine=True))
    return report
