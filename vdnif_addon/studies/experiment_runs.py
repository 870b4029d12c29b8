"""The runs behind the experiments (``experiments``): their sizes, the variant and settings
of each run's label, one scene's runs trained with every seed and compared on one common
pixel set (their medians), the rest pose's "original" views and the comparison figures."""

import dataclasses
import pathlib
import re
import statistics
import sys

import numpy as np

from ..blender.image_io import save_image
from ..blender.resolution import recipe_resolution
from ..blender.scenes import demo_scene
from ..blender.steps import (
    evaluate_file,
    evaluation_poses,
    training_capture,
    variant_dataset,
)
from ..inference import images
from ..inference.evaluation import REFERENCES, compare_common, concatenated, distance_range
from ..model.variants import variant_config
from ..pose_sets import TEST_POSES, PoseSpec
from ..posed.geometry import PosedObject
from ..posed.render import orbit_view
from ..settings import RECIPE
from ..tracing.rays import orbit_viewpoints
from ..tracing.references import true_reference
from ..training.fit import fit_model
from .report import common_pixels_line

# The full size trains with the default recipe (``settings.RECIPE``: voxel resolution,
# poses, rays per pose and their mix, steps, batch), the one place it is set; the experiments
# add their evaluation and seeds. Its resolution None is the recipe's for each scene's mesh
# (``Recipe.resolution_for``). The quick size is a tiny one for tests.
SIZES = {
    "full": dict(resolution=None, poses=RECIPE.poses,
                 rays_per_pose=RECIPE.rays_per_pose, steps=RECIPE.steps,
                 overrides=dict(batch_size=RECIPE.batch_size), eval_poses=8, width=256,
                 height=256, seeds=(0, 1, 2)),
    "quick": dict(resolution=12, poses=3, rays_per_pose=128, steps=20, eval_poses=2,
                  width=24, height=16, seeds=(0, 1),
                  overrides=dict(log2_table_size=10, batch_size=1024)),
}
PI_FORM = "proposed, sin(pi 2^k x)"
PAPER_LOSS = "proposed, log-MSE of d/h"
RUNS = {   # label: (variant, extra settings)
    "lsnif": ("lsnif", {}),
    "deformed": ("deformed", {}),
    "proposed": ("proposed", {}),
    PI_FORM: ("proposed", {"pe_form": "pi"}),
    PAPER_LOSS: ("proposed", {"distance_mode": "log-distance"}),
    "no positional encoding": ("proposed-no-pe", {}),
    "no log distance": ("proposed-no-log", {}),
    "no uncertainty weighting": ("proposed-no-uncertainty", {}),
}


class Experiment:
    """Shared set-up of one experiment run: sizes, seeds, scenes, scratch and figures
    folders, and the ``suffix`` of its figures' names (a narrowed run's seeds, so that a
    one-seed run does not replace the figure of a run over every seed)."""

    def __init__(self, size, scratch, figures, device, progress, scenes, suffix=""):
        self.size, self.scratch, self.figures = size, pathlib.Path(scratch), figures
        self.device, self.progress, self.scenes = device, progress, scenes
        self.suffix = suffix
        self.resolutions = {}   # scene object's name -> voxel resolution it ran at
        self.follows = {}       # scene object's name -> how its corners followed in training

    def overrides(self, extra=None, seed=0):
        return dict(self.size["overrides"], steps=self.size["steps"], device=self.device,
                    seed=seed, **(extra or {}))

    @property
    def spec(self):
        """The training poses of every run: random poses of seed 0."""
        return PoseSpec(count=self.size["poses"])

    def scene(self, name):
        """(object, training capture) of a demo scene."""
        obj = demo_scene(name)
        captured = training_capture(obj, self.resolution(obj), self.spec,
                                    say=lambda line: self.say(f"'{obj.name}': {line}"))
        self.follows[obj.name] = captured.corners_follow
        return obj, captured

    def resolution(self, obj):
        """The size's voxel resolution, or the recipe's for ``obj``'s mesh."""
        if obj.name not in self.resolutions:
            self.resolutions[obj.name] = self.size["resolution"] or recipe_resolution(obj)
        return self.resolutions[obj.name]

    def evaluation(self, obj, rest=False):
        """Test poses (``pose_sets.POSE_SETS``: the reported tables choose nothing) disjoint
        from the training poses, or views of the rest pose."""
        return evaluation_poses(obj, self.resolution(obj), self.spec, rest=rest,
                                count=self.size["eval_poses"], pose_set=TEST_POSES,
                                follow=self.follows.get(obj.name))

    def evaluate(self, obj, evaluated, model, viewpoints=None, seen=False):
        return evaluate_file(obj, evaluated, model, self.size["width"], self.size["height"],
                             self.device, viewpoints=viewpoints, seen=seen)

    def say(self, text):
        print(f"experiment: {text}", file=sys.stderr, flush=True)


@dataclasses.dataclass
class SceneRuns:
    """Every run of one scene: per label its per-seed reports (each with its metrics on the
    scene's common pixel set under ``common``) and medians, the joined references of the
    evaluation views, and the first view of seed 0 per label for the figures."""

    obj: object
    captured: object
    evaluated: object
    labels: tuple
    seeds: tuple
    reports: dict           # label -> [report per seed]
    medians: dict           # label -> {"vs_true", "vs_embedded"}: medians on the common set
    references: dict        # "true" | "embedded" -> Passes of every evaluation view joined
    first_views: dict       # label -> the first evaluation view of seed 0
    common_note: str

    @property
    def voxel_size(self):
        return self.captured.grid.voxel_size


def run_scene(run, scene, labels, rest=False):
    """Trains every run of ``labels`` with every seed on ``scene`` (runs on the same kind of
    data share one dataset per seed), evaluates them on the same views, and compares them
    on one common pixel set: the pixels where every run of every seed and the reference
    hit."""
    obj, captured = run.scene(scene)
    evaluated = run.evaluation(obj, rest=rest)
    seeds = tuple(run.size["seeds"])
    reports = {label: [] for label in labels}
    predicted = {label: [] for label in labels}
    references, first_views = None, {}
    for number, seed in enumerate(seeds):
        datasets = {}
        for index, label in enumerate(labels):
            variant, extra = RUNS[label]
            run.say(f"{scene}: {label}, seed {seed} ({number * len(labels) + index + 1} of "
                    f"{len(seeds) * len(labels)})")
            deformed_data = variant_config(variant).deformed_data
            folder = run.scratch / f"{scene}-data-{int(deformed_data)}-seed{seed}"
            if deformed_data not in datasets:
                datasets[deformed_data] = variant_dataset(
                    obj, captured, variant, folder, run.size["rays_per_pose"], seed=seed)
            model = run.scratch / f"{_tag(scene, label)}-seed{seed}.vdnif"
            result, _ = fit_model(folder, variant, model, run.overrides(extra, seed),
                                  progress=run.progress)
            report, views = run.evaluate(obj, evaluated, model)
            report["seed"] = seed
            # held-out validation along the way: did the steps suffice?
            report["validation_history"] = [{"step": r["step"], **(r["validation"] or {})}
                                            for r in result.history]
            report["dataset"] = {"rays": datasets[deformed_data].counts.rays,
                                 "segments": datasets[deformed_data].counts.segments,
                                 "seed": seed}
            joined = concatenated(views)
            references = _same_references(references, joined, scene)
            reports[label].append(report)
            predicted[label].append(joined["predicted"])
            if number == 0:
                first_views[label] = views[0]
    runs = [(label, i) for label in labels for i in range(len(seeds))]
    common = compare_common([dict(references, predicted=predicted[label][i])
                             for label, i in runs], captured.mesh,
                            [captured.grid.voxel_size] * len(runs))
    for (label, i), metrics in zip(runs, common):
        reports[label][i]["common"] = dict(metrics, models=list(labels), seeds=list(seeds))
    medians = {label: median_metrics([r["common"] for r in reports[label]])
               for label in labels}
    note = common_pixels_line([f"{scene}: {label}" for label in labels], common[0],
                              len(seeds))
    return SceneRuns(obj, captured, evaluated, tuple(labels), seeds, reports, medians,
                     references, first_views, note)


def _same_references(kept, joined, scene):
    """The references of the first run, checked equal to those of every later run (the
    same rays, poses and casts): one copy of them is kept per scene."""
    if kept is None:
        return {name: joined[name] for name in REFERENCES}
    for name in REFERENCES:
        if not (np.array_equal(kept[name].hit, joined[name].hit)
                and np.array_equal(kept[name].distance, joined[name].distance)):
            raise RuntimeError(f"{scene}: the {name} reference differs between runs on the "
                               "same views")
    return kept


def median_metrics(results):
    """{"vs_true", "vs_embedded"}: per metric the median over ``results`` (compare_both
    dicts, one per seed); None where any seed has none."""
    medians = {}
    for name in REFERENCES:
        keys = results[0][f"vs_{name}"]
        medians[f"vs_{name}"] = {
            key: (None if any(r[f"vs_{name}"][key] is None for r in results) else
                  statistics.median(r[f"vs_{name}"][key] for r in results))
            for key in keys}
    return medians


def scene_record(runs, label):
    """The JSON record of one label: medians on the common pixel set (``common``, what the
    table shows), per-seed reports, median training time and the model's bytes."""
    reports = runs.reports[label]
    return {"common": runs.medians[label], "seeds": reports,
            "timings": {"train_s": statistics.median(r["timings"]["train_s"]
                                                     for r in reports)},
            "model_bytes": reports[0]["model_bytes"]}


def table_rows(scene, runs):
    """The table's rows (label, medians vs true, medians vs embedded) and the spread
    table's rows (label, per-seed metrics) of a scene's runs."""
    rows, spreads = [], []
    for label in runs.labels:
        name = f"{scene}: {label}"
        median = runs.medians[label]
        rows.append((name, median["vs_true"], median["vs_embedded"]))
        spreads.append((name, [r["common"] for r in runs.reports[label]]))
    return rows, spreads


def original_views(run, runs):
    """The paper's "original": per evaluation view the true reference of the rest pose, cast
    with the very rays of that view of the deformed pose (the orbit camera framing the
    deformed object): what a model of the rest pose alone would be asked to match. Returns
    per view its Passes, material as the object's slots."""
    obj, evaluated, mesh = runs.obj, runs.evaluated, runs.captured.mesh
    viewpoints = orbit_viewpoints(len(evaluated.poses))
    passes = []
    with PosedObject(obj, evaluated) as posed_object:
        for pose, viewpoint in zip(evaluated.poses, viewpoints):
            origins, directions = orbit_view(posed_object.geometry(pose), viewpoint,
                                             run.size["width"], run.size["height"])
            rest = posed_object.rest_geometry()
            passes.append(true_reference(mesh, rest.mesh_caster(mesh.triangles), origins,
                                         directions).with_slots(mesh.material_slots))
    return passes


def scene_figure(run, name, reference, shown, errors, object_size):
    """One figure of the first evaluation view: the columns ``shown`` [(title, Passes)]
    on one distance scale, then the error heat maps of ``errors`` [(title, Passes)]
    against ``reference``; one row per pass. Returns (path, column titles)."""
    height, width = run.size["height"], run.size["width"]
    near_far = distance_range(*(passes for _, passes in shown))
    columns = [images.display(passes, height, width, near_far) for _, passes in shown]
    columns += [images.error_images(passes, reference, height, width, object_size)
                for _, passes in errors]
    path = run.figures / name
    save_image(path, images.comparison_figure([[column[p] for column in columns]
                                               for p in images.PASSES]))
    titles = [title for title, _ in shown] + [f"error of {title}" for title, _ in errors]
    return path, titles


def _tag(scene, label):
    return re.sub(r"\W+", "-", f"{scene}-{label}").strip("-").lower()
