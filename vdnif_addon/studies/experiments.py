"""The paper's experiments, one command each, written as sections of ``docs/results.md``:

- ``static``: one static pose (the rest pose): lsnif (trained on that pose) vs deformed vs
  proposed (trained on random poses) on spot and the bunny: the paper's Table 1;
- ``deformation``: deformed vs proposed on unseen poses of the armature arm, the lattice
  Suzanne, the textured spot (armature) and the three-material bunny (lattice), with the
  paper's "original" column (the rest pose's reference on the same views): its Figure 3;
- ``ablation``: proposed with each of its three parts removed in turn (positional encoding,
  log distance with ReLU, uncertainty weighting) and with the other sinusoid form
  ``sin(pi 2^k x)``, against deformed and proposed on arm, lattice and spot;
- ``per-pose``: one lsnif trained per unseen pose (the upper bound) vs one proposed model
  for all of them, with the cost of each in training time and bytes.

Where training is random, every run is trained with each seed of the size (the dataset's
rays and the training's initialization, batches and held-out poses; the training and
evaluation poses stay those of pose seed 0) and the tables give the median over seeds of
each metric, all taken over one common pixel set per scene (DESIGN section 10); the runs
themselves (training, evaluation, medians, figures) are in ``experiment_runs``.
"""

import dataclasses
import datetime
import os
import pathlib
import re
import shlex
import tempfile
import time

import torch

from ..blender.steps import variant_dataset
from ..errors import VDNIFError
from ..inference.evaluation import compare_both, compare_common, concatenated
from ..model.provenance import stamp
from ..output_rule import REPORT_FORMAT
from ..passes import Passes
from ..posed.generate import generate_dataset
from ..safe_io import write_json_atomic
from ..settings import RECIPE
from ..text import value
from ..tracing.rays import orbit_viewpoints
from ..training.fit import fit_model
from .experiment_runs import (
    PAPER_LOSS,
    PI_FORM,
    RUNS,
    SIZES,
    Experiment,
    original_views,
    run_scene,
    scene_figure,
    scene_record,
    table_rows,
)
from .report import (
    common_pixels_line,
    metrics_table,
    settled,
    spread_table,
    targets_line,
    write_section,
)

RESULTS_PREAMBLE = ("# Results of the paper's experiments\n\nEach section is written by the "
                    "command it names; numbers are measured, not copied.\n")
ABLATION_RUNS = ("deformed", "proposed", "no positional encoding", "no log distance",
                 "no uncertainty weighting", PI_FORM, PAPER_LOSS)
SCENES = {"static": ("spot", "bunny"), "deformation": ("arm", "lattice", "spot", "bunny"),
          "ablation": ("arm", "lattice", "spot"), "per-pose": ("arm",)}
ORIGINAL = "original (rest pose)"
FIGURE_PASSES = "rows: normal, albedo, distance, material"


def static(run):
    """Table 1: every variant on the rest pose of spot and the bunny."""
    labels = ("lsnif", "deformed", "proposed")
    rows, spreads, records, figures, notes, goals = [], [], {}, [], [], []
    for scene in run.scenes:
        runs = run_scene(run, scene, labels, rest=True)
        scene_rows, scene_spreads = table_rows(scene, runs)
        rows += scene_rows
        spreads += scene_spreads
        records.update({f"{scene}/{label}": scene_record(runs, label) for label in labels})
        notes.append(f"- {runs.common_note}")
        goals.append(targets_line(scene, runs.medians["proposed"], rates=False))
        view = runs.first_views
        figures.append(scene_figure(
            run, f"static-{scene}{run.suffix}.png", view["proposed"]["true"],
            [("reference", view["proposed"]["true"])]
            + [(label, view[label]["predicted"]) for label in labels],
            [(label, view[label]["predicted"]) for label in labels],
            runs.captured.mesh.size))
    lines = [
        "lsnif trains on the rest pose alone (as many rays as all poses of the others); "
        "deformed and proposed train on random poses; all are evaluated on "
        f"{run.size['eval_poses']} views of the rest pose. Each figure is the median over "
        f"{_seeds(run)}.", "",
        metrics_table(rows), "", *notes, "",
        "Targets (Table 1: proposed distance MAE and normal error at most the paper's "
        "proposed figures):", "", *goals, "",
        "Spread over the seeds (same pixel sets):", "", spread_table(spreads), "",
        _cost_table(records), "", *_figure_lines(figures)]
    return records, lines


def deformation(run):
    """Figure 3: deformed vs proposed on unseen poses of the arm, the lattice Suzanne, the
    textured spot and the three-material bunny, with the rest pose's reference."""
    labels = ("deformed", "proposed")
    rows, spreads, records, figures, notes, goals = [], [], {}, [], [], []
    for scene in run.scenes:
        runs = run_scene(run, scene, labels)
        scene_rows, scene_spreads = table_rows(scene, runs)
        original = original_views(run, runs)
        joined = Passes.concatenate(original)
        mesh, h = runs.captured.mesh, runs.voxel_size
        compared = compare_both(joined, runs.references["true"], runs.references["embedded"],
                                mesh, h)
        rows += scene_rows + [(f"{scene}: {ORIGINAL}", compared["vs_true"],
                               compared["vs_embedded"])]
        spreads += scene_spreads
        records.update({f"{scene}/{label}": scene_record(runs, label) for label in labels})
        records[f"{scene}/{ORIGINAL}"] = compared
        notes.append(f"- {runs.common_note} The {ORIGINAL} row: the rest pose's true "
                     "reference on the same rays, over its own pixels (where it and the "
                     "reference both hit).")
        goals.append(targets_line(scene, runs.medians["proposed"], runs.medians["deformed"],
                                  seeds=(_per_seed(runs, "proposed"),
                                         _per_seed(runs, "deformed"))))
        view = runs.first_views
        figures.append(scene_figure(
            run, f"deformation-{scene}{run.suffix}.png", view["proposed"]["true"],
            [("deformed", view["deformed"]["predicted"]),
             ("proposed", view["proposed"]["predicted"]),
             ("reference", view["proposed"]["true"]), ("original", original[0])],
            [("deformed", view["deformed"]["predicted"]),
             ("proposed", view["proposed"]["predicted"])], mesh.size))
    lines = [
        f"Both train on the same {run.size['poses']} random poses and are evaluated on "
        f"{run.size['eval_poses']} test poses (a seed of their own, disjoint "
        "from the training poses by construction), one orbit view each at "
        f"{run.size['width']}x{run.size['height']}. Each figure is the median over "
        f"{_seeds(run)}. spot is textured (albedo from its image), the bunny has three "
        f"material slots. The {ORIGINAL} row is the paper's \"original\": the rest pose "
        "rendered with the same rays, what a model trained on the rest pose alone (LSNIF) "
        "would be asked to match, against the deformed pose's references.", "",
        metrics_table(rows), "", *notes, "",
        "Targets (proposed: false-negative and false-positive rates each at most "
        "0.5 %, distance MAE and normal error at most the paper's proposed figures, against "
        "both references; albedo PSNR on spot, material accuracy on the bunny; and better "
        "than deformed on every metric):", "", *goals, "",
        "Spread over the seeds (same pixel sets):", "", spread_table(spreads), "",
        _cost_table(records), "", *_figure_lines(figures)]
    return records, lines


def ablation(run):
    """Proposed with each of its parts removed in turn (positional encoding, log distance
    with ReLU, uncertainty weighting), with sin(pi 2^k x) and with the paper's log-MSE of
    d/h, against deformed and proposed on the arm, the lattice Suzanne and spot."""
    rows, spreads, records, notes, effects = [], [], {}, [], []
    for scene in run.scenes:
        runs = run_scene(run, scene, ABLATION_RUNS)
        scene_rows, scene_spreads = table_rows(scene, runs)
        rows += scene_rows
        spreads += scene_spreads
        records.update({f"{scene}/{label}": scene_record(runs, label)
                        for label in ABLATION_RUNS})
        notes.append(f"- {runs.common_note}")
        effects.append(_ablation_line(scene, runs))
    parts = ", ".join(f"{label} (`{RUNS[label][0]}`)" for label in ABLATION_RUNS[2:5])
    lines = [
        f"Every run trains on the same data ({run.size['poses']} random poses, the same "
        f"rays per seed) for the same {run.size['steps']} steps and is evaluated on "
        f"{run.size['eval_poses']} test poses at {run.size['width']}x{run.size['height']}; "
        f"each figure is the median over {_seeds(run)}. The ablations each take one part of "
        f"proposed back to the deformed baseline's: {parts}; `{PI_FORM}` is proposed with "
        f"the PEPS sinusoids instead of the paper's `sin(2^k x)`; `{PAPER_LOSS}` is proposed "
        "with the paper's distance as written: ReLU log1p(d/h) of the rest distance from the "
        "segment's start in voxel edges, its MSE in log space (DESIGN section 8). A "
        "difference is settled where the seeds' ranges do not overlap.", "",
        metrics_table(rows), "", *notes, "",
        "What each change does to proposed (medians against the true reference, common "
        "pixel set; the rates over every pixel):", "", *effects, "",
        "Spread over the seeds (same pixel sets):", "", spread_table(spreads), "",
        _cost_table(records)]
    return records, lines


def _per_seed(runs, label):
    """The per-seed results of ``label`` on the scene's common pixel set."""
    return [report["common"] for report in runs.reports[label]]


def _ablation_line(scene, runs):
    """How each ablation's medians differ from proposed's, each difference marked settled
    or not by the seeds (``report.settled``)."""
    base, base_seeds = runs.medians["proposed"]["vs_true"], _per_seed(runs, "proposed")

    def change(label, m, name, pick):
        seeds = [pick(result["vs_true"]) for result in _per_seed(runs, label)]
        ours = [pick(result["vs_true"]) for result in base_seeds]
        return f"{name} {_change(pick(m), pick(base))} ({settled(seeds, ours)})"

    parts = []
    for label in ABLATION_RUNS[2:]:
        m = runs.medians[label]["vs_true"]
        parts.append(", ".join([
            f"{label}: " + change(label, m, "distance MAE", lambda r: r["distance_mae"]),
            change(label, m, "normal error", lambda r: r["normal_error_deg"]),
            change(label, m, "holes + extras", _holes_extras)]))
    return f"- {scene}: " + "; ".join(parts) + "."


def _holes_extras(metrics):
    rates = (metrics["false_negative_rate"], metrics["false_positive_rate"])
    return None if None in rates else sum(rates)


def _change(number, base):
    if number is None or base is None or base == 0:
        return "n/a"
    return f"{100 * (number / base - 1):+.0f} %"


def per_pose(run):
    """One lsnif per unseen pose of the arm (the upper bound) vs one proposed model."""
    obj, captured = run.scene("arm")
    evaluated = run.evaluation(obj)
    viewpoints = orbit_viewpoints(len(evaluated.poses))
    model = run.scratch / "arm-proposed.vdnif"
    variant_dataset(obj, captured, "proposed", run.scratch / "arm", run.size["rays_per_pose"])
    fit_model(run.scratch / "arm", "proposed", model, run.overrides(), progress=run.progress)
    proposed, proposed_views = run.evaluate(obj, evaluated, model)
    views, train_s, model_bytes = [], 0.0, 0
    rays = run.size["rays_per_pose"] * run.size["poses"]
    for index, pose in enumerate(evaluated.poses):
        run.say(f"arm: lsnif for pose {index + 1} of {len(evaluated.poses)}")
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
    upper_label = f"lsnif per pose ({len(evaluated.poses)} models)"
    labels = ("proposed (one model)", upper_label)
    common = compare_common([concatenated(proposed_views), joined], captured.mesh, [h, h])
    records = {"arm/proposed": proposed, "arm/lsnif per pose": upper}
    rows = []
    for label, record, metrics in zip(labels, records.values(), common):
        record["common"] = dict(metrics, models=list(labels))
        rows.append((label, metrics["vs_true"], metrics["vs_embedded"]))
    lines = [
        f"{len(evaluated.poses)} test poses of the arm, one seed (0). The upper bound "
        f"trains one lsnif network per pose on that pose alone ({rays:,} rays each, through "
        "the same voxel embedding), so it pays training and storage once per pose; the "
        f"proposed model is trained once on {run.size['poses']} other poses.", "",
        metrics_table(rows), "", f"- {common_pixels_line(labels, common[0])}", "",
        _cost_table(records)]
    return records, lines


EXPERIMENTS = {"static": static, "deformation": deformation, "ablation": ablation,
               "per-pose": per_pose}


def _slug(text):
    return re.sub(r"\W+", "-", text).strip("-")


def run_name(name, scenes, seeds, all_seeds):
    """(section key, file name stem, figure suffix) of a run of experiment ``name``: a run
    narrowed to some of its ``scenes`` or to fewer ``seeds`` than the size's ``all_seeds``
    names them, so that it writes its own section, JSON and figures beside a run of the
    whole experiment (``experiment deformation, spot, 1 seed``: ``deformation-spot-1-seed``
    and ``deformation-spot-1-seed.png``; figure names hold their scene already)."""
    scene_part = list(scenes) if set(scenes) != set(SCENES[name]) else []
    seed_part = ([f"{len(seeds)} seed{'s' if len(seeds) > 1 else ''}"]
                 if len(seeds) < len(all_seeds) else [])
    parts = [name, *scene_part, *seed_part]
    return ("experiment " + ", ".join(parts), _slug("-".join(parts)),
            "".join(f"-{_slug(part)}" for part in seed_part))


def ran_line(started, wall_s, threads):
    """When and how a run ran: its UTC date and times, its wall time and the threads."""
    end = started + datetime.timedelta(seconds=wall_s)
    day = started.strftime("%Y-%m-%d") + ("" if end.date() == started.date()
                                          else end.strftime("/%d"))
    return (f"Ran on {day} from {started:%H:%M} to {end:%H:%M} UTC (wall "
            f"{wall_s / 60:.0f} min, torch on {threads} thread{'s' if threads > 1 else ''}, "
            f"{os.cpu_count()} CPU cores).")


def run_experiment(name, results, quick=False, device="auto", progress=None, command=None,
                   scenes=None, seeds=None):
    """Runs experiment ``name`` and rewrites its section of the markdown file ``results``;
    figures and the JSON of every run go to the folder ``results/../results/``. ``scenes``
    (default: all of the experiment's) and ``seeds`` (how many of the size's seeds,
    default all) narrow a run; a narrowed run has its own section and files
    (``run_name``)."""
    size = dict(SIZES["quick" if quick else "full"])
    chosen = tuple(scenes or SCENES[name])
    unknown = sorted(set(chosen) - set(SCENES[name]))
    if unknown:
        raise VDNIFError(f"experiment {name} has no scene {', '.join(unknown)}: choose from "
                         f"{', '.join(SCENES[name])}")
    if name == "per-pose":      # trains its models with seed 0 alone
        size["seeds"] = size["seeds"][:1]
    all_seeds = size["seeds"]
    if seeds is not None:
        size["seeds"] = size["seeds"][:max(1, seeds)]
    section, stem, figure_suffix = run_name(name, chosen, size["seeds"], all_seeds)
    results = pathlib.Path(results)
    figures = results.parent / "results"
    figures.mkdir(parents=True, exist_ok=True)
    started, clock = datetime.datetime.now(datetime.timezone.utc), time.monotonic()
    with tempfile.TemporaryDirectory(prefix="vdnif-experiment-") as scratch:
        run = Experiment(size, scratch, figures, device, progress, chosen, figure_suffix)
        records, lines = EXPERIMENTS[name](run)
    settings = {key: size[key] for key in ("resolution", "poses", "rays_per_pose", "steps",
                                           "eval_poses", "width", "height")}
    if settings["resolution"] is None:      # the recipe's of each scene's mesh
        used = set(run.resolutions.values())
        settings["resolution"] = used.pop() if len(used) == 1 else dict(run.resolutions)
    # the training rays' mix is the recipe's at every size (generate_dataset's default)
    settings.update(size["overrides"], surface_fraction=RECIPE.surface_fraction,
                    grazing_fraction=RECIPE.grazing_fraction,
                    secondary_fraction=RECIPE.secondary_fraction, seeds=list(size["seeds"]),
                    torch_threads=torch.get_num_threads())
    # the training times of its tables depend on the machine and its load: recorded with it
    write_json_atomic(figures / f"{stem}.json", stamp(
        {"format": REPORT_FORMAT, "experiment": name, "settings": settings,
         "scenes": list(chosen), "runs": records}, with_machine=True))
    command = command or shlex.join(
        ["python", "vdnif_addon/batch.py", "--", "experiment", name]
        + (["--quick"] if quick else []) + (["--scenes", ",".join(chosen)] if scenes else [])
        + (["--seeds", str(seeds)] if seeds is not None else []))
    body = [f"Command: `{command}`", "",
            "Settings: " + ", ".join(f"{k} {v}" for k, v in settings.items()) +
            f". Every run's JSON: `{figures.name}/{stem}.json`. "
            + ran_line(started, time.monotonic() - clock, torch.get_num_threads()), "",
            *lines]
    title = " ".join(EXPERIMENTS[name].__doc__.split())
    if set(chosen) != set(SCENES[name]):     # a narrowed run says which scenes it holds
        title += f" This run: {', '.join(chosen)}."
    write_section(results, section, f"{name}: {title}", body, RESULTS_PREAMBLE)
    return records


def _seeds(run):
    seeds = run.size["seeds"]
    return (f"{len(seeds)} seeds ({', '.join(map(str, seeds))})" if len(seeds) > 1
            else f"1 seed ({seeds[0]})")


def _cost_table(records):
    lines = ["| run | training time (s, median) | model bytes |", "| --- | --- | --- |"]
    for label, report in records.items():
        if "timings" in report:
            lines.append(f"| {label} | {value(report['timings']['train_s'], 4)} | "
                         f"{report['model_bytes']:,} |")
    lines += ["", "Training times: the run's trainings one after another in one process, on "
              "the machine and load its JSON records (`provenance.machine`); compare them "
              "within this table, not with a model trained alone."]
    return "\n".join(lines)


def _figure_lines(figures):
    """The figures, after one line that says what their columns and rows are."""
    titles = figures[0][1] if figures else []
    lines = [f"Figures: the first evaluation view of seed 0; columns: {', '.join(titles)}; "
             f"{FIGURE_PASSES}. Error maps: distance bright at 0.05 object units, normal at "
             "45 deg, albedo at 0.25, a wrong material red; white where only one of the two "
             "hits.", ""]
    return lines + [f"![{path.stem}](results/{path.name})" for path, _ in figures]
