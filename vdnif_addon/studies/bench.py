"""The speed/accuracy sweep behind ``batch.py -- bench``: the proposed variant trained and
evaluated on unseen poses of the arm while one setting at a time moves away from a base
(voxel resolution, hash levels and table size, PE bands, MLP width). Every point trains to
the same convergence rule (``training.stopping``), so the front compares converged models, not
models stopped at one step count. Writes CSV, JSON, Pareto plots and a section of
``docs/performance.md`` (``bench_report``) and the presets derived from the front, less
those not measurably faster than a more accurate one (``pareto.derive_presets``).

Only points that predict hits (``metrics.speed_withheld``) have a speed, and their errors
are compared on one common pixel set (DESIGN section 10): the front and the presets come
from them alone."""

import json
import pathlib
import shlex
import sys
import tempfile

import numpy as np

from ..blender.scenes import demo_scene
from ..blender.steps import evaluate_file, evaluation_poses, training_capture, variant_dataset
from ..errors import VDNIFError
from ..inference.evaluation import compare_common, concatenated
from ..model.model_file import load_model
from ..model.provenance import provenance, stamp
from ..pose_sets import DEVELOPMENT_POSES, PoseSpec
from ..presets import PRESET_ERROR, PRESET_VARIANT, PRESETS_FORMAT, SPEED_ROUNDS
from ..safe_io import exclusive_lock, write_json_atomic
from ..settings import RECIPE, NetworkConfig, TrainConfig
from ..training.fit import fit_model
from .bench_report import NO_PRESETS, point_label, sweep_markdown, write_outputs
from .pareto import derive_presets
from .report import write_section

# The base point is the default recipe (``settings.RECIPE``: resolution, poses, rays per pose
# and their mix, batch) with the network's default architecture; the full sweep moves one
# setting at a time from it, and every point trains by the recipe's own stopping rule and
# step cap, so that a preset is a point a user's training reaches. Points render at 256x256,
# as every other table does: a 96x96 render lasts tens of milliseconds, where per-call costs
# and a point's place in the round set its speed (the base point measured 191 k rays/s there,
# between its width neighbours' 272 k and 213 k). The quick size is a small one for tests.
_NETWORK, _TRAIN = NetworkConfig(), TrainConfig()
SIZES = {
    "full": dict(
        poses=RECIPE.poses, rays_per_pose=RECIPE.rays_per_pose, speed_rounds=7,
        eval_poses=4, width=256, height=256, overrides=dict(batch_size=RECIPE.batch_size),
        base=dict(resolution=RECIPE.resolution, levels=_NETWORK.levels,
                  log2_table_size=_NETWORK.log2_table_size, pe_bands=_NETWORK.pe_bands,
                  width=_NETWORK.width),
        axes={"resolution": [16, 32, 64], "grid": [(2, 14), (2, 16), (4, 18)],
              "pe_bands": [0, 3, 6], "width": [32, 64, 128]},
        convergence=dict(validate_every=_TRAIN.log_interval, patience=_TRAIN.stop_patience,
                         min_gain=_TRAIN.stop_min_gain, max_steps=RECIPE.steps)),
    "quick": dict(
        poses=4, rays_per_pose=1024, eval_poses=2, width=32, height=24, speed_rounds=2,
        overrides=dict(batch_size=4096),
        base=dict(resolution=16, levels=2, log2_table_size=12, pe_bands=3, width=64),
        axes={"resolution": [12, 16], "grid": [(2, 10), (2, 12)], "pe_bands": [0, 3],
              "width": [32, 64]},
        convergence=dict(validate_every=50, patience=3, min_gain=0.02, max_steps=600)),
}
METRICS = ("distance_mae", "distance_mae_voxels", "normal_error_deg", "hit_iou",
           "false_negative_rate", "false_positive_rate")
COMMON_METRICS = ("distance_mae", "distance_mae_voxels", "normal_error_deg")
PERFORMANCE_PREAMBLE = "# Performance\n\nEach section names the command that measured it.\n"


def rule_overrides(convergence):
    """The TrainConfig settings of a size's convergence rule (``training.stopping``): at most
    ``max_steps`` steps, the learning rate decaying over them for every point alike."""
    return {"steps": convergence["max_steps"], "log_interval": convergence["validate_every"],
            "stop_patience": convergence["patience"], "stop_min_gain": convergence["min_gain"]}


def sweep_points(base, axes):
    """The base settings and each one-setting variation of them, without repeats."""
    points = [dict(base)]
    for axis, values in axes.items():
        for entry in values:
            changed = dict(zip(("levels", "log2_table_size"), entry)) if axis == "grid" else {
                axis: entry}
            point = dict(base, **changed)
            if point not in points:
                points.append(point)
    return points


def run_bench(out, presets_path, work, performance=None, quick=False, device="auto",
              progress=None, command=None):
    """Runs the sweep; writes ``bench.csv``, ``bench.json`` and ``pareto.png`` into ``out``,
    the presets to ``presets_path`` (only when a point predicts hits) and, if given, its
    section of ``performance``. Each point's model and training record stay in ``work``:
    a sweep that stopped (the full one trains for hours) resumes there, training
    only the points not yet finished with the same settings, and evaluates every point again
    in this run, so that the speeds are compared within one process.

    Several runs on one ``work`` folder share the training: a point being trained holds
    its lock (``safe_io.exclusive_lock``), and the others pass it by. A run that finds,
    after its own points, one still training in another run stops there; the run that
    finishes last evaluates every point, alone. Returns (rows, the (presets, dropped) of
    ``pareto.derive_presets`` or why there are none), or (None, None) when this run left the
    evaluation to another."""
    size = SIZES["quick" if quick else "full"]
    out, work = pathlib.Path(out), pathlib.Path(work)
    work.mkdir(parents=True, exist_ok=True)
    obj = demo_scene("arm")
    spec = PoseSpec(count=size["poses"])
    points = sweep_points(size["base"], size["axes"])
    with tempfile.TemporaryDirectory(prefix="vdnif-bench-") as scratch:
        scratch = pathlib.Path(scratch)
        busy = _train_points(obj, spec, size, points, range(len(points)), work, scratch,
                             device, progress)
        # a point another run was training when this one passed it: finished since, or
        # left by a run that stopped (its lock went with it), which this run trains now
        busy = _train_points(obj, spec, size, points, busy, work, scratch, device, progress)
    if busy:
        print(f"bench: point{'s' if len(busy) > 1 else ''} "
              f"{', '.join(str(n + 1) for n in busy)} still training in another bench run on "
              f"{work}; this run trained its share and stops: the run that finishes last "
              "evaluates every point", file=sys.stderr, flush=True)
        return None, None
    evaluation = exclusive_lock(work / "evaluate.lock")
    if evaluation is None:
        print(f"bench: another bench run on {work} is evaluating every point; this run stops",
              file=sys.stderr, flush=True)
        return None, None
    with evaluation:
        rows = _evaluate_points(obj, spec, size, points, work, device)
    return rows, publish_sweep(rows, out, presets_path, performance, quick, command)


def publish_sweep(rows, out, presets_path, performance=None, quick=False, command=None):
    """Writes a sweep's ``rows`` (``_evaluate_points``'s) into ``out``, the presets they
    derive (``pareto.derive_presets``) to ``presets_path`` and, if given, its section of
    ``performance``; returns the (presets, dropped) or why there are none."""
    out, size = pathlib.Path(out), SIZES["quick" if quick else "full"]
    # No presets from models that do not predict hits, nor from a sweep with too few points
    # for three distinct ones: the presets file is then left as it was, and the section
    # says why.
    derived, no_presets = None, NO_PRESETS
    if any(row["speed_withheld"] is None for row in rows):
        try:
            derived = derive_presets(rows, PRESET_ERROR)
        except VDNIFError as error:
            no_presets = str(error)
    out.mkdir(parents=True, exist_ok=True)
    write_outputs(out, rows)
    if derived is not None:
        presets, dropped = derived
        write_json_atomic(presets_path, stamp({"format": PRESETS_FORMAT,
                                               "source": "bench" + (" --quick" if quick else ""),
                                               "error": PRESET_ERROR, "presets": presets,
                                               "dropped": dropped}),
                          "presets file")
    if performance is not None:
        command = command or shlex.join(["python", "vdnif_addon/batch.py", "--", "bench"]
                                        + (["--quick"] if quick else []))
        write_section(performance, "bench", "Speed/accuracy sweep",
                      sweep_markdown(rows, derived or no_presets, size, command, out,
                                     performance),
                      PERFORMANCE_PREAMBLE)
    return derived or no_presets


def _point_files(work, number):
    """(model file, training record) of sweep point ``number`` in ``work``."""
    return work / f"point-{number}.vdnif", work / f"point-{number}.json"


def _train_points(obj, spec, size, points, numbers, work, scratch, device, progress):
    """Trains the points ``numbers`` not yet finished in ``work`` whose lock this run gets;
    returns the numbers of those another run holds (being trained there)."""
    busy = []
    for number in numbers:
        point = points[number]
        model, path = _point_files(work, number)
        if finished_point(path, model, size, point) is not None:
            continue
        lock = exclusive_lock(work / f"point-{number}.lock")
        if lock is None:
            print(f"bench: point {number + 1} of {len(points)} is training in another bench "
                  "run; passed by", file=sys.stderr, flush=True)
            busy.append(number)
            continue
        with lock:
            if finished_point(path, model, size, point) is not None:
                continue        # another run finished it between the two looks
            print(f"bench: point {number + 1} of {len(points)}: {point_label(point)}",
                  file=sys.stderr, flush=True)
            # a resolution's dataset is built when its first point trains here, so that a
            # resumed sweep builds none for the points it only evaluates
            data = scratch / f"r{point['resolution']}"
            if not data.exists():
                captured = training_capture(obj, point["resolution"], spec,
                                            say=_say(f"resolution {point['resolution']}"))
                variant_dataset(obj, captured, PRESET_VARIANT, data, size["rays_per_pose"])
            write_json_atomic(path, _train_point(data, model, size, point, device, progress))
    return busy


def _say(subject):
    """A line's printer to stderr, beginning with the bench and ``subject``."""
    return lambda line: print(f"bench: {subject}: {line}", file=sys.stderr, flush=True)


def _evaluate_points(obj, spec, size, points, work, device):
    """Every point's model evaluated on the development poses (``pose_sets.POSE_SETS``: the
    presets and the front are choices) of its resolution, in this one process: the CSV's rows
    with the common-set errors. One short render times a point only roughly, so each renders
    once per round for ``speed_rounds`` rounds, the rounds interleaved (every point once, then
    again), and its speed is the median; the rows keep every round's speed too (SPEED_ROUNDS,
    None where the speed is withheld), their spread being the protocol's noise. Its errors
    are the first round's. Each model's corners follow as they did in its training."""
    files = [_point_files(work, number) for number in range(len(points))]
    follows = [load_model(model)[1].corners_follow for model, _ in files]
    scenes = {(resolution, follow): evaluation_poses(
                  obj, resolution, spec, count=size["eval_poses"], pose_set=DEVELOPMENT_POSES,
                  follow=follow)
              for resolution, follow in sorted({(p["resolution"], f)
                                                for p, f in zip(points, follows)})}
    records = [finished_point(path, model, size, point)
               for (model, path), point in zip(files, points)]
    first, speeds = [], [[] for _ in points]
    for round_ in range(size["speed_rounds"]):
        for number, point in enumerate(points):
            if round_ == 0:
                print(f"bench: point {number + 1} of {len(points)} evaluated from "
                      f"{files[number][0]} ({records[number]['steps']:,} steps)",
                      file=sys.stderr, flush=True)
            evaluated = scenes[point["resolution"], follows[number]]
            report, views = evaluate_file(obj, evaluated, files[number][0], size["width"],
                                          size["height"], device)
            speeds[number].append(report["timings"]["render_rays_per_s"])
            if round_ == 0:
                first.append((report, (concatenated(views), evaluated.grid.voxel_size)))
    rows = [_row(dict(point, steps=record["steps"], converged=record["converged"]), report,
                 record.get("provenance"), None if None in rounds else rounds)
            for (report, _), point, record, rounds in zip(first, points, records, speeds)]
    _add_common(rows, [run for _, run in first], evaluated.mesh)
    return rows


def _train_point(data, model, size, point, device, progress):
    """Trains one sweep point on the dataset folder ``data`` to the convergence rule into
    ``model``; its record."""
    settings = {k: v for k, v in point.items() if k != "resolution"}
    result, _ = fit_model(data, PRESET_VARIANT, model,
                          dict(size["overrides"], device=device, **settings,
                               **rule_overrides(size["convergence"])),
                          progress=progress)
    # the point's training time is measured here: its record names the machine and load
    return {"key": point_key(size, point), "steps": result.steps,
            "converged": result.status == "converged",
            "provenance": provenance(with_machine=True)}


def point_key(size, point):
    """What a point's training depends on: its settings and the size's data, batch and
    convergence rule (JSON-normal, so that a record read back compares equal)."""
    fixed = {k: size[k] for k in ("poses", "rays_per_pose", "overrides", "convergence")}
    return json.loads(json.dumps({"point": point, **fixed}))


def finished_point(path, model, size, point):
    """The record of a point an earlier run finished with the same key (its model beside
    it), else None: a missing, unreadable or foreign record means the point trains again."""
    try:
        record = json.loads(pathlib.Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("key") != point_key(size, point) \
            or not pathlib.Path(model).is_file():
        return None
    return record


def _row(point, report, trained=None, rounds=None):
    """One point's row; ``trained``: its training record's provenance (None where it trained
    before records had one); ``rounds``: its rays/s in each timing round, whose median is its
    speed (None: the report's one timing is)."""
    row = dict(point)
    for reference in ("vs_true", "vs_embedded"):
        for key in METRICS:
            row[f"{reference}_{key}"] = report[reference][key]
    timings = report["timings"]
    speed = timings["render_rays_per_s"] if rounds is None else float(np.median(rounds))
    row.update({"train_s": timings["train_s"], "render_rays_per_s": speed,
                SPEED_ROUNDS: None if rounds is None else [float(r) for r in rounds],
                "speed_withheld": report["speed_withheld"],
                "model_bytes": report["model_bytes"]})
    if trained is not None:
        row["provenance"] = trained
    return row


def _add_common(rows, runs, mesh):
    """Adds ``common_<reference>_<metric>`` to every row: the errors over the common pixel
    set of the points that have a speed (they predict hits); None for the others."""
    compared = [i for i, row in enumerate(rows) if row["speed_withheld"] is None]
    common = compare_common([runs[i][0] for i in compared], mesh,
                            [runs[i][1] for i in compared]) if compared else []
    by_row = dict(zip(compared, common))
    for i, row in enumerate(rows):
        for reference in ("vs_true", "vs_embedded"):
            metrics = by_row.get(i, {}).get(reference, {})
            for key in COMMON_METRICS + ("compared_rays",):
                row[f"common_{reference}_{key}"] = metrics.get(key)
