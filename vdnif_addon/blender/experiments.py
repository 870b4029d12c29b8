"""The paper's experiments, one command each, written as sections of ``docs/results.md``:

- ``static``: one static pose (the rest pose): lsnif (trained on that pose) vs deformed vs
  proposed (trained on random poses) on spot and the bunny: the paper's Table 1;
- ``deformation``: deformed vs proposed on ``arm`` and ``lattice``, unseen poses, with the
  proposed encoding's sinusoid form measured both ways (``sin(2^k x)`` and ``sin(pi 2^k x)``);
- ``per-pose``: one lsnif trained per unseen pose (the upper bound) vs one proposed model
  for all of them, with the cost of each in training time and bytes.
"""

import dataclasses
import json
import pathlib
import re
import shlex
import tempfile

import torch

from ..evaluation import compare_both, compare_common, concatenated, figure
from ..fit import fit_model
from ..rays import orbit_viewpoints
from ..report import common_pixels_line, goal_line, metrics_table, value, write_section
from .capture import capture
from .generate import generate_dataset
from .image_io import save_image
from .jobs import evaluate_file, evaluation_poses, train_variant
from .poses import PoseSpec
from .scenes import demo_scene

SIZES = {
    "full": dict(resolution=32, poses=32, rays_per_pose=4096, steps=1500, eval_poses=4,
                 width=128, height=128, overrides={}),
    "quick": dict(resolution=12, poses=3, rays_per_pose=128, steps=20, eval_poses=2,
                  width=24, height=16, overrides=dict(log2_table_size=10, batch_size=1024)),
}
RESULTS_PREAMBLE = ("# Results of the paper's experiments\n\nEach section is written by the "
                    "command it names; numbers are measured, not copied.\n")
RUNS = {   # label: (variant, extra settings)
    "lsnif": ("lsnif", {}),
    "deformed": ("deformed", {}),
    "proposed": ("proposed", {}),
    "proposed, sin(pi 2^k x)": ("proposed", {"pe_form": "pi"}),
}


class Experiment:
    """Shared set-up of one experiment run: sizes, scratch folder, figures folder."""

    def __init__(self, size, scratch, figures, device, progress):
        self.size, self.scratch, self.figures = size, pathlib.Path(scratch), figures
        self.device, self.progress = device, progress

    def overrides(self, extra=None):
        return dict(self.size["overrides"], steps=self.size["steps"], device=self.device,
                    **(extra or {}))

    @property
    def spec(self):
        """The training poses of every run: random poses of seed 0."""
        return PoseSpec(count=self.size["poses"])

    def scene(self, name):
        """(object, training capture) of a demo scene."""
        obj = demo_scene(name)
        return obj, capture(obj, self.size["resolution"], self.spec, deform_corners=False)

    def evaluation(self, obj, rest=False):
        """Evaluation poses disjoint from the training poses (or views of the rest pose)."""
        return evaluation_poses(obj, self.size["resolution"], self.spec, rest=rest,
                                count=self.size["eval_poses"])

    def train_and_evaluate(self, obj, captured, evaluated, label):
        """Trains run ``label`` of RUNS on ``captured``, evaluates it on ``evaluated``:
        (report, views)."""
        variant, extra = RUNS[label]
        tag = re.sub(r"\W+", "-", f"{obj.name}-{label}").strip("-").lower()
        model = self.scratch / f"{tag}.vdnif"
        train_variant(obj, captured, variant, self.scratch / tag, self.size["rays_per_pose"],
                      model, self.overrides(extra), progress=self.progress)
        return self.evaluate(obj, evaluated, model)

    def evaluate(self, obj, evaluated, model, viewpoints=None, seen=False):
        return evaluate_file(obj, evaluated, model, self.size["width"], self.size["height"],
                             self.device, viewpoints=viewpoints, seen=seen)

    def figure(self, name, views, object_size):
        """reference | prediction | error of the first view, against the true reference."""
        path = self.figures / name
        save_image(path, figure(views[0]["true"], views[0]["predicted"], self.size["height"],
                                self.size["width"], object_size))
        return path


def compared(records, views, labels, mesh, voxel_sizes):
    """Adds to each record of ``labels`` its metrics on the common pixel set of these
    models (``records[label]["common"]``, DESIGN section 10); returns the table rows and
    the line that says what the errors are taken over."""
    common = compare_common([concatenated(views[label]) for label in labels], mesh,
                            voxel_sizes)
    rows = []
    for label, metrics in zip(labels, common):
        records[label]["common"] = dict(metrics, models=list(labels))
        rows.append((label, metrics["vs_true"], metrics["vs_embedded"]))
    return rows, common_pixels_line(labels, common[0])


def static(run):
    """Table 1: every variant on the rest pose of spot and the bunny."""
    rows, records, figures, notes = [], {}, [], []
    for scene in ("spot", "bunny"):
        obj, captured = run.scene(scene)
        evaluated = run.evaluation(obj, rest=True)
        views, labels = {}, []
        for label in ("lsnif", "deformed", "proposed"):
            report, views[f"{scene}: {label}"] = run.train_and_evaluate(obj, captured,
                                                                         evaluated, label)
            records[f"{scene}/{label}"] = report
            labels.append(f"{scene}: {label}")
            figures.append(run.figure(f"static-{scene}-{label}.png", views[labels[-1]],
                                      captured.mesh.size))
        scene_rows, note = compared(_keyed(records, scene), views, labels, captured.mesh,
                                    [captured.grid.voxel_size] * len(labels))
        rows += scene_rows
        notes.append(f"- {note}")
    lines = [
        "lsnif trains on the rest pose alone (as many rays as all poses of the others); "
        "deformed and proposed train on random poses; all are evaluated on "
        f"{run.size['eval_poses']} views of the rest pose.", "",
        metrics_table(rows), "", *notes, "", _cost_table(records), "",
        *_figure_lines(figures)]
    return records, lines


def deformation(run):
    """Deformed vs proposed on unseen poses of the armature arm and the lattice Suzanne."""
    rows, records, figures, goals, notes = [], {}, [], [], []
    for scene in ("arm", "lattice"):
        obj, captured = run.scene(scene)
        evaluated = run.evaluation(obj)
        views, labels = {}, []
        for label in ("deformed", "proposed", "proposed, sin(pi 2^k x)"):
            report, views[f"{scene}: {label}"] = run.train_and_evaluate(obj, captured,
                                                                         evaluated, label)
            records[f"{scene}/{label}"] = report
            labels.append(f"{scene}: {label}")
            if label != "proposed, sin(pi 2^k x)":
                figures.append(run.figure(f"deformation-{scene}-{label}.png",
                                          views[labels[-1]], captured.mesh.size))
        scene_rows, note = compared(_keyed(records, scene), views, labels, captured.mesh,
                                    [captured.grid.voxel_size] * len(labels))
        rows += scene_rows
        notes.append(f"- {note}")
        proposed = records[f"{scene}/proposed"]["common"]
        deformed = records[f"{scene}/deformed"]["common"]
        beats = all(_better(proposed[ref], deformed[ref]) for ref in ("vs_true", "vs_embedded"))
        goals.append(f"- {scene}: {goal_line(proposed['vs_embedded'])} Proposed "
                     f"{'beats' if beats else 'does not beat'} the deformed baseline on "
                     "distance and normal error against both references (common pixel set).")
    lines = [
        f"Both train on the same {run.size['poses']} random poses and are evaluated on "
        f"{run.size['eval_poses']} other random poses (another seed, disjoint from the "
        "training poses by construction).", "",
        metrics_table(rows), "", *notes, "", *goals, "", _cost_table(records), "",
        *_figure_lines(figures)]
    return records, lines


def per_pose(run):
    """One lsnif per unseen pose of the arm (the upper bound) vs one proposed model."""
    obj, captured = run.scene("arm")
    evaluated = run.evaluation(obj)
    viewpoints = orbit_viewpoints(len(evaluated.poses))
    proposed, proposed_views = run.train_and_evaluate(obj, captured, evaluated, "proposed")
    views, train_s, model_bytes = [], 0.0, 0
    rays = run.size["rays_per_pose"] * run.size["poses"]
    for index, pose in enumerate(evaluated.poses):
        one = dataclasses.replace(captured, poses=[pose])
        folder, model = run.scratch / f"pose-{index}", run.scratch / f"pose-{index}.vdnif"
        generate_dataset(obj, one, folder, rays, seed=index)
        fit_model(folder, "lsnif", model, run.overrides(), progress=run.progress)
        # The upper bound is trained on the very pose it is evaluated on, by design.
        report, pose_views = run.evaluate(obj, dataclasses.replace(evaluated, poses=[pose]),
                                          model, viewpoints[index:index + 1], seen=True)
        views += pose_views
        train_s += report["timings"]["train_s"]
        model_bytes += report["model_bytes"]
    joined = concatenated(views)
    h = captured.grid.voxel_size
    upper = {**compare_both(joined["predicted"], joined["true"], joined["embedded"],
                            captured.mesh, h),
             "timings": {"train_s": train_s}, "model_bytes": model_bytes}
    records = {"arm/proposed": proposed, "arm/lsnif per pose": upper}
    upper_label = f"lsnif per pose ({len(evaluated.poses)} models)"
    labels = ("proposed (one model)", upper_label)
    rows, note = compared({labels[0]: proposed, labels[1]: upper},
                          {labels[0]: proposed_views, labels[1]: views}, labels,
                          captured.mesh, [h, h])
    lines = [
        f"{len(evaluated.poses)} unseen poses of the arm. The upper bound trains one lsnif "
        f"network per pose on that pose alone ({rays:,} rays each, through the same voxel "
        "embedding), so it pays training and storage once per pose; the proposed model is "
        f"trained once on {run.size['poses']} other poses.", "",
        metrics_table(rows), "", f"- {note}", "",
        _cost_table(records)]
    return records, lines


def _keyed(records, scene):
    """The records of ``scene`` under their table labels ("scene: run"), the same dicts."""
    return {key.replace("/", ": ", 1): record for key, record in records.items()
            if key.startswith(f"{scene}/")}


EXPERIMENTS = {"static": static, "deformation": deformation, "per-pose": per_pose}


def run_experiment(name, results, quick=False, device="auto", progress=None, command=None):
    """Runs experiment ``name`` and rewrites its section of the markdown file ``results``;
    figures and the JSON of every run go to the folder ``results/../results/``."""
    size = SIZES["quick" if quick else "full"]
    results = pathlib.Path(results)
    figures = results.parent / "results"
    figures.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="vdnif-experiment-") as scratch:
        records, lines = EXPERIMENTS[name](Experiment(size, scratch, figures, device,
                                                      progress))
    settings = {key: size[key] for key in ("resolution", "poses", "rays_per_pose", "steps",
                                           "eval_poses", "width", "height")}
    settings.update(size["overrides"], torch_threads=torch.get_num_threads())
    (figures / f"{name}.json").write_text(json.dumps(
        {"experiment": name, "settings": settings, "runs": records}, indent=2) + "\n")
    command = command or shlex.join(["python", "vdnif_addon/batch.py", "--", "experiment",
                                     name] + (["--quick"] if quick else []))
    body = [f"Command: `{command}`", "",
            "Settings: " + ", ".join(f"{k} {v}" for k, v in settings.items()) +
            f". Every run's JSON: `{figures.name}/{name}.json`.", "", *lines]
    write_section(results, f"experiment {name}", f"{name}: {EXPERIMENTS[name].__doc__.strip()}",
                  body, RESULTS_PREAMBLE)
    return records


def _better(a, b):
    return all(a[key] is not None and b[key] is not None and a[key] < b[key]
               for key in ("distance_mae", "normal_error_deg"))


def _cost_table(records):
    lines = ["| run | training time (s) | model bytes |", "| --- | --- | --- |"]
    for label, report in records.items():
        lines.append(f"| {label} | {value(report['timings']['train_s'], 4)} | "
                     f"{report['model_bytes']:,} |")
    return "\n".join(lines)


def _figure_lines(paths):
    lines = ["Figures (first evaluation view; columns: true reference, prediction, error; "
             "rows: normal, albedo, distance, material):", ""]
    return lines + [f"![{path.stem}](results/{path.name})" for path in paths]
