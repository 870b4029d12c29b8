"""The outputs of the speed/accuracy sweep (``bench``): ``bench.csv``, ``bench.json``, the
Pareto plots and the sweep's section of ``docs/performance.md``."""

import csv
import itertools
import pathlib

import numpy as np

from ..inference.metrics import SPEED_MIN_HIT_IOU
from ..presets import PRESET_ERROR, SETTINGS, SPEED_ROUNDS
from ..safe_io import atomic_path, write_json_atomic
from ..text import percent, value
from .pareto import pareto_front, round_ratios, speed_range

NO_PRESETS = (f"no sweep point predicts hits (hit IoU at least {SPEED_MIN_HIT_IOU} against the "
              "true reference): nothing to compare, no presets derived")


def write_outputs(out, rows):
    """bench.csv, bench.json and pareto.png (error vs render speed and vs training time)."""
    flat = [_flat(row) for row in rows]
    with atomic_path(out / "bench.csv", "CSV file") as temporary, \
            open(temporary, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(flat[0]), extrasaction="ignore")
        writer.writeheader()
        writer.writerows(flat)
    write_json_atomic(out / "bench.json", rows)
    _plot(out / "pareto.png", rows)


def _flat(row):
    """``row`` as a line of bench.csv: its timing rounds as their slowest and fastest
    (``render_rays_per_s_min`` / ``_max``, empty where it has none), and without its
    provenance (commit, network, machine), the JSON's nested record."""
    flat = {}
    for key, entry in row.items():
        if key == SPEED_ROUNDS:
            flat["render_rays_per_s_min"], flat["render_rays_per_s_max"] = (
                speed_range(row) or (None, None))
        elif key != "provenance":
            flat[key] = entry
    return flat


def speed_spread(row):
    """The spread of ``row``'s timing rounds, (max - min) / median (its speed), None where it
    has none: the timing protocol's noise on that point."""
    extent = speed_range(row)
    return None if extent is None else (extent[1] - extent[0]) / row["render_rays_per_s"]


def _speed(figures):
    """A speed with the range of its timing rounds, "n/a" without a speed."""
    speed, extent = figures.get("render_rays_per_s"), speed_range(figures)
    if speed is None:
        return "n/a"
    return f"{speed:,.0f}" + (f" ({extent[0]:,.0f}-{extent[1]:,.0f})" if extent else "")


def timing_text(rows, rounds):
    """The timing protocol of a sweep of ``rounds`` rounds and the noise its ``rows``
    measured: the largest spread of a point's rounds and the median point's, and the median
    spread of two points' round-by-round ratio, which the comparisons read."""
    spreads = [(spread, point_label(r)) for r in rows
               if (spread := speed_spread(r)) is not None]
    protocol = (f"Render speed: {rounds} rounds, each rendering every point once in turn (the "
                "rounds interleaved, so that a change in the machine's load falls on every "
                "point alike). A point's speed is the median of its rounds; their spread, "
                "(max - min) / median, is the timing's noise on it")
    if not spreads:
        return protocol + ": not measured here, as no point has a speed."
    largest = max(spreads)
    paired = [np.ptp(ratios) / np.median(ratios)
              for a, b in itertools.combinations(rows, 2)
              if (ratios := round_ratios(a, b)) is not None]
    # a single timed point has no pair to spread
    pairs = (f" The ratio of two points' speeds spreads over the rounds by "
             f"{percent(float(np.median(paired)))} for the median pair ((max - min) / median "
             "ratio)." if paired else "")
    return (protocol + f": at most {percent(largest[0])} here ({largest[1]}), "
            f"{percent(float(np.median([s for s, _ in spreads])))} on the median point. Two "
            "speeds are compared round by round: one differs measurably from the other when "
            "it is faster in every round (by chance one time in "
            f"{2 ** rounds:,} with {rounds} rounds)." + pairs)


def _plot(path, rows):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    usable = [r for r in rows
              if r[PRESET_ERROR] is not None and r["render_rays_per_s"] is not None]
    error = [r[PRESET_ERROR] for r in usable]
    figure, axes = pyplot.subplots(1, 2, figsize=(11, 4.2))
    if not usable:                      # no point to put on a log scale: say why
        for ax in axes:
            ax.set_axis_off()
        figure.text(0.5, 0.5, NO_PRESETS.replace(": ", ":\n"), ha="center", va="center",
                    fontsize=12)
        with atomic_path(path, "plot") as temporary:
            figure.savefig(temporary, dpi=120)
        pyplot.close(figure)
        return
    for ax, key, label, cost in (
            (axes[0], "render_rays_per_s", "neural render (rays/s)", lambda v: 1 / v),
            (axes[1], "train_s", "training time (s)", lambda v: v)):
        x = [r[key] for r in usable]
        front = pareto_front(error, [cost(v) for v in x])
        ax.scatter(x, error, color="0.6", label="sweep point")
        ax.plot([x[i] for i in front], [error[i] for i in front], "o-", color="C3",
                label="Pareto front")
        # A label runs to the right of its point, or to the left in the right third of the
        # (log) axis: about 30 characters at 6 pt would otherwise leave the figure.
        lo, hi = np.log(min(x)), np.log(max(x))
        for r, xv, yv in zip(usable, x, error):
            left = hi > lo and (np.log(xv) - lo) / (hi - lo) > 2 / 3
            ax.annotate(point_label(r), (xv, yv), fontsize=6, xytext=(-3 if left else 3, 3),
                        textcoords="offset points", ha="right" if left else "left")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("distance MAE vs true reference\n(object units, common pixels)")
        ax.legend(fontsize=7)
    figure.tight_layout()
    with atomic_path(path, "plot") as temporary:
        figure.savefig(temporary, dpi=120)
    pyplot.close(figure)


def _machine(row):
    """The machine record of ``row``'s provenance (where and as it ran), {} without one."""
    return (row.get("provenance") or {}).get("machine") or {}


def _threads(rows):
    """The torch threads the sweep's points recorded (their provenance), in words."""
    counts = sorted({str(_machine(r)["torch_threads"]) for r in rows
                     if "torch_threads" in _machine(r)})
    return (f"torch on {' or '.join(counts)} CPU thread(s)" if counts
            else "torch's CPU threads not recorded")


def _load(row):
    """`` (load L)``: the machine's 1-minute load average as ``row``'s training ended, or
    nothing where its provenance has none."""
    load = _machine(row).get("load_average")
    return f" (load {load[0]:.1f})" if load else ""


def _load_text(rows):
    """What a training time in the table is measured on and under."""
    machines = sorted({f"{m['cpu']}, {m['cores']} cores" for m in map(_machine, rows)
                       if "cpu" in m and "cores" in m})
    if not machines:
        return ("The points recorded neither machine nor load: their training times do not "
                "compare.")
    return ("Each point's training ran on " + "; ".join(machines) + ", and its time is given "
            "with the machine's 1-minute load average as it ended: points trained in separate "
            "runs beside other work, whose times compare only at like loads.")


def point_label(row):
    """A point's settings in short: R32 L2 T16 F3 W64, and S<steps> once trained."""
    return (f"R{row['resolution']} L{row['levels']} T{row['log2_table_size']} "
            f"F{row['pe_bands']} W{row['width']}"
            + (f" S{row['steps']}" if "steps" in row else ""))


def rule_text(convergence):
    """The convergence rule of ``Convergence`` in words, with the size's numbers."""
    return (f"Every point trains until the stopping rule ends it: the training validates on its "
            f"held-out training poses every {convergence['validate_every']} steps, and stops "
            f"once {convergence['patience']} validations in a row ("
            f"{convergence['patience'] * convergence['validate_every']:,} steps) have not "
            f"lowered any of the held-out occlusion error, distance MAE (voxels) and normal "
            f"error by more than {100 * convergence['min_gain']:g} % below its last mark; "
            f"at most {convergence['max_steps']:,} steps (a point stopped there says so), "
            f"the learning rate decaying over those {convergence['max_steps']:,} steps for "
            "every point. Training time is the time to that stop, the rule's or the cap's.")


def sweep_markdown(rows, presets, size, command, out, performance):
    """The lines of the sweep's section of docs/performance.md: its protocol and timing noise,
    its table, its plot and ``presets``, the (presets, dropped) of ``pareto.derive_presets``
    (or why there are none, a text)."""
    relative = pathlib.Path(out).resolve().relative_to(
        pathlib.Path(performance).resolve().parent) if performance else out
    compared = [r for r in rows if r["speed_withheld"] is None]
    pixels = compared[0]["common_vs_true_compared_rays"] if compared else 0
    lines = [f"Command: `{command}`", "",
             f"The proposed variant on the `arm` scene: {size['poses']} random training poses "
             f"x {size['rays_per_pose']} rays, evaluated on {size['eval_poses']} development "
             f"poses at {size['width']}x{size['height']}, {_threads(rows)}. "
             "One setting moves at a time from the base "
             + ", ".join(f"{k} {v}" for k, v in size["base"].items()) + ".", "",
             rule_text(size["convergence"]) + " " + _load_text(rows), "",
             timing_text(rows, size["speed_rounds"]), "",
             f"Only points that predict hits (hit IoU at least {SPEED_MIN_HIT_IOU} against "
             f"the true reference) have a speed, {len(compared)} of {len(rows)} here; their "
             f"distance and normal errors are taken over one common pixel set, the {pixels:,} "
             "pixels where every one of them and the reference hit (against the embedded "
             "reference: where each hits its own resolution's embedding). The other points "
             "show n/a (their errors over their own hits are in bench.json). Hit IoU and the "
             "false-negative / false-positive rates (shares of the true reference's hits) "
             "count every pixel.",
             "",
             "| R | L | log2 T | F | width | steps (converged) | distance MAE true / embedded "
             "| distance MAE true (voxels) | normal error true / embedded (deg) "
             "| hit IoU (true) | false neg. / pos. (true) | train (s) | render rays/s "
             "(rounds min-max) | spread | model bytes |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- "
             "| --- | --- |"]
    for r in rows:
        lines.append(
            f"| {r['resolution']} | {r['levels']} | {r['log2_table_size']} | {r['pe_bands']} | "
            f"{r['width']} | {r['steps']:,} ({'yes' if r['converged'] else 'no: cap'}) | "
            f"{value(r['common_vs_true_distance_mae'])} / "
            f"{value(r['common_vs_embedded_distance_mae'])} | "
            f"{value(r['common_vs_true_distance_mae_voxels'], 3)} | "
            f"{value(r['common_vs_true_normal_error_deg'], 3)}"
            f" / {value(r['common_vs_embedded_normal_error_deg'], 3)} | "
            f"{value(r['vs_true_hit_iou'])} | {percent(r['vs_true_false_negative_rate'])} / "
            f"{percent(r['vs_true_false_positive_rate'])} | {r['train_s']:.1f}{_load(r)} | "
            f"{_speed(r)} | {percent(speed_spread(r))} | {r['model_bytes']:,} |")
    lines += ["", f"![Pareto fronts]({relative}/pareto.png)", ""]
    if isinstance(presets, str):
        return lines + [f"Presets: n/a, {presets}.", "",
                        f"Raw figures: `{relative}/bench.csv`, `{relative}/bench.json`."]
    presets, dropped = presets
    lines += [f"Presets (the panel's preset menu), from the front of {PRESET_ERROR} vs render "
              "speed: fast is its fastest point, accurate its most accurate, balanced the knee "
              "of the points between them (closest to the ideal corner in log space); where "
              "the front has no point between them, balanced is the point nearest the front "
              "(the smallest gain, the same factor in speed and in error, that would put it "
              "there). A preset not measurably faster than the next more accurate one kept "
              "would trade a larger error for no speed that the timing can show: it is "
              "dropped, and the more accurate one stays.",
              "", "| preset | " + " | ".join(SETTINGS) + " | distance MAE | rays/s (rounds "
              "min-max) |",
              "| --- | " + " | ".join("---" for _ in SETTINGS) + " | --- | --- |"]
    for name, preset in presets.items():
        measured = preset["measured"]
        lines.append(f"| {name} | " + " | ".join(str(preset[k]) for k in SETTINGS)
                     + f" | {value(measured[PRESET_ERROR])} | {_speed(measured)} |")
    for line in ([f"Dropped: {name}, {reason}." for name, reason in dropped.items()]
                 or ["Dropped: none, each preset was faster in every round than the next "
                     "more accurate one."]):
        lines += ["", line]
    lines += ["", f"Raw figures: `{relative}/bench.csv`, `{relative}/bench.json`."]
    return lines
