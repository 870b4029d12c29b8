"""Markdown for people: the demo's report, the tables of the experiments and benchmarks, and
the sections that each command rewrites in a shared document."""

import pathlib
import re

from ..inference.metrics import CLEAN_RATE, verdict
from ..passes import COMPOSITOR_PASSES, SECONDARY_COMPOSITOR, SHADED_COMPOSITOR
from ..safe_io import write_text_atomic
from ..text import EMBREE_NOTE, EXACT_PATH, percent, shaded_line, speed_line, value

# The paper's proposed figures (DESIGN section 10), the accuracy goal of the deformed scenes
# and of Table 1: at most these, against both references.
PAPER_PROPOSED = {"distance_mae": 0.039, "normal_error_deg": 11.8}
# The holes and extras a proposed model may leave: at most these shares of the reference's
# hits, against both references.
RATE_TARGETS = {"false_negative_rate": 0.005, "false_positive_rate": 0.005}
# What the textured and the multi-material scene must predict: at least these.
SCENE_TARGETS = {"spot": {"albedo_psnr": 30.0}, "bunny": {"material_accuracy": 0.99}}
# Every metric of a comparison table, with the direction in which it is better.
HIGHER_IS_BETTER = {"distance_mae": False, "normal_error_deg": False, "hit_iou": True,
                    "false_negative_rate": False, "false_positive_rate": False,
                    "albedo_psnr": True, "material_accuracy": True}
NAMES = {"distance_mae": "distance MAE", "normal_error_deg": "normal error",
         "hit_iou": "hit IoU", "false_negative_rate": "false negatives",
         "false_positive_rate": "false positives", "albedo_psnr": "albedo PSNR",
         "material_accuracy": "material accuracy"}
REFERENCES = ("true", "embedded")


def metrics_table(rows):
    """A markdown table of (label, vs_true metrics, vs_embedded metrics) rows: the distance
    error in object units and in voxels (it travels across scenes), the hit-mask metrics
    (hit IoU and the false-negative and false-positive rates, over the reference's hits) and
    the scene's optional metrics (n/a where the scene has nothing to predict)."""
    lines = ["| | reference | distance MAE (object units) | distance MAE (voxels) | normal "
             "error (deg) | hit IoU | false negatives | false positives | albedo PSNR (dB) "
             "| material accuracy |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for label, vs_true, vs_embedded in rows:
        for name, m in (("true", vs_true), ("embedded", vs_embedded)):
            lines.append(f"| {label} | {name} | {value(m['distance_mae'])} | "
                         f"{value(m.get('distance_mae_voxels'), 3)} | "
                         f"{value(m['normal_error_deg'], 3)} | {value(m['hit_iou'])} | "
                         f"{percent(m.get('false_negative_rate'))} | "
                         f"{percent(m.get('false_positive_rate'))} | "
                         f"{value(m.get('albedo_psnr'), 3)} | "
                         f"{value(m.get('material_accuracy'), 3)} |")
    return "\n".join(lines)


def secondary_table(vs_true, vs_embedded):
    """A markdown table of the AO and shadow errors against each reference
    (``metrics.compare_secondary``): from the network's own hits and from the true ones
    (the secondary rays' own error, without the primary hits')."""
    lines = ["| reference | AO MAE | AO MAE (true hits) | false lit | false lit (true hits) "
             "| false shadow | false shadow (true hits) |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, m in (("true", vs_true), ("embedded", vs_embedded)):
        cells = [value(m[f"ao_mae{suffix}"], 3) for suffix in ("", "_true_hit")]
        cells += [percent(m[f"shadow_{kind}_rate{suffix}"]) for kind in ("false_lit",
                                                                           "false_shadow")
                  for suffix in ("", "_true_hit")]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def secondary_section(report):
    """The demo report's AO and shadow lines: what was cast, the table and the figure; none
    for a report without them."""
    if "ao_mae" not in report["vs_true"]:
        return []
    shown = report["secondary"]
    return [
        f"Ambient occlusion ({shown['ao_samples']} rays per hit pixel, looking "
        f"{value(shown['ao_distance'])} object units) and shadow (towards {shown['light']}), "
        f"from the network's own hits (pushed {value(shown['network_offset'], 3)} object "
        f"units off the surface) and from the true hits (pushed {value(shown['offset'])}): "
        "AO MAE is the mean absolute difference of the unoccluded share; false lit are the "
        "reference's shadowed hits the network lights, false shadow its lit hits the network "
        "shadows.",
        "",
        secondary_table(report["vs_true"], report["vs_embedded"]),
        "",
        *([f"The shaded image (the albedo under that light and the scene's world, against the "
           f"true reference shaded alike; the terminator band |N.L| < "
           f"{shown['terminator_band']}): {shaded_line(report['vs_true'])}.", ""]
          if "shaded_psnr" in report["vs_true"] else []),
        "![AO and shadow: reference, predicted, error](figure-secondary-vs-true.png)",
        "",
    ]


def common_pixels_line(labels, metrics, seeds=1):
    """What the errors of the compared models ``labels`` (each trained with ``seeds``
    seeds) are taken over (DESIGN section 10), from one of their compare_both results on
    the common pixel set."""
    counts = {name: metrics[f"vs_{name}"]["compared_rays"] for name in REFERENCES}
    models = (f"all {len(labels)} models" if seeds == 1 else
              f"all {len(labels)} models x {seeds} seeds ({len(labels) * seeds} trainings)")
    return (f"{', '.join(labels)}: distance, normal, albedo and material errors over the "
            f"same pixels, where {models} and the reference hit (the common pixel set: "
            f"{counts['true']:,} pixels against the true reference, {counts['embedded']:,} "
            "against the embedded one); hit IoU and the false-negative and false-positive "
            "rates over every pixel, the rates as shares of the reference's hits.")


def metric_text(key, number):
    """One metric's value as the tables write it (rates in percent, units named)."""
    if number is None:
        return "n/a"
    if key.endswith("_rate"):
        return percent(number)
    if key == "normal_error_deg":
        return f"{value(number, 3)} deg"
    if key == "albedo_psnr":
        return f"{value(number, 3)} dB"
    return value(number, 4 if key == "distance_mae" else 3)


def spread_table(rows):
    """The spread over seeds: rows of (label, [compare_both result per seed]) as the
    smallest and largest value of the headline metrics against each reference."""
    keys = ("distance_mae", "normal_error_deg", "false_negative_rate", "false_positive_rate")
    lines = ["| | reference | seeds | " + " | ".join(f"{NAMES[k]} (min - max)" for k in keys)
             + " |", "| --- | --- | --- | " + " | ".join("---" for _ in keys) + " |"]
    for label, per_seed in rows:
        for name in REFERENCES:
            cells = []
            for key in keys:
                numbers = [m[f"vs_{name}"].get(key) for m in per_seed]
                cells.append("n/a" if None in numbers else
                             f"{metric_text(key, min(numbers))} - "
                             f"{metric_text(key, max(numbers))}")
            lines.append(f"| {label} | {name} | {len(per_seed)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def target_checks(scene, metrics, rates=True):
    """[(text, met)]: the targets of ``scene`` for a proposed model's ``metrics``
    ({"vs_true", "vs_embedded"}): the hole and extra rates (with ``rates``), the paper's
    distance and normal figures, and the scene's own (SCENE_TARGETS), each against both
    references."""
    bounds = [(key, bound, True) for key, bound in
              ({**RATE_TARGETS, **PAPER_PROPOSED} if rates else PAPER_PROPOSED).items()]
    bounds += [(key, bound, False) for key, bound in SCENE_TARGETS.get(scene, {}).items()]
    checks = []
    for key, bound, at_most in bounds:
        numbers = [metrics[f"vs_{name}"].get(key) for name in REFERENCES]
        met = all(n is not None and (n <= bound if at_most else n >= bound) for n in numbers)
        checks.append((f"{NAMES[key]} {' / '.join(metric_text(key, n) for n in numbers)} "
                       f"{'<=' if at_most else '>='} {metric_text(key, bound)}", met))
    return checks


SETTLED, NOT_SETTLED = "settled", "not settled"


def settled(ours, theirs):
    """Whether a difference between two runs is an effect: ``SETTLED`` when their seeds'
    values (lists, at least two each) span ranges that do not overlap, else ``NOT_SETTLED``
    (a difference inside the seed spread, or one seed, says nothing)."""
    ours, theirs = [v for v in ours if v is not None], [v for v in theirs if v is not None]
    if min(len(ours), len(theirs)) < 2:
        return NOT_SETTLED
    apart = max(ours) < min(theirs) or max(theirs) < min(ours)
    return SETTLED if apart else NOT_SETTLED


def seed_values(seeds, name, key):
    """The values of metric ``key`` against reference ``name`` over per-seed compare_both
    results (empty without seeds)."""
    return [result[f"vs_{name}"].get(key) for result in seeds or ()]


def beat_checks(proposed, baseline, seeds=None):
    """[(text, beaten)]: per metric and reference where both have a value, whether
    ``proposed`` is strictly better than ``baseline`` (compare_both results: the medians).
    ``seeds``: (proposed's, baseline's) per-seed results, to say of each difference whether
    the seeds settle it (``settled``)."""
    return [(text, beaten) for text, beaten, _ in _beats(proposed, baseline, seeds)]


def _beats(proposed, baseline, seeds):
    """``beat_checks``' pairs with a third value: whether the seeds settle the difference
    (False without ``seeds``)."""
    checks = []
    for name in REFERENCES:
        for key, higher in HIGHER_IS_BETTER.items():
            a, b = proposed[f"vs_{name}"].get(key), baseline[f"vs_{name}"].get(key)
            if a is None or b is None:
                continue
            verdict, firm = "", False
            if seeds is not None:
                verdict = settled(seed_values(seeds[0], name, key),
                                  seed_values(seeds[1], name, key))
                firm, verdict = verdict == SETTLED, ", " + verdict
            checks.append((f"{NAMES[key]} vs {name} ({metric_text(key, a)} vs "
                           f"{metric_text(key, b)}{verdict})", a > b if higher else a < b, firm))
    return checks


def targets_line(scene, proposed, deformed=None, rates=True, seeds=None):
    """One line for ``scene``: which targets the proposed model's metrics meet and which
    not, and, given the deformed baseline's, on which metrics proposed beats it; with
    ``seeds`` (see ``beat_checks``) how many of those differences the seeds settle."""
    checks = target_checks(scene, proposed, rates)
    met = [text for text, ok in checks if ok]
    missed = [text for text, ok in checks if not ok]
    line = (f"- **{scene}** (values against the true / embedded reference): targets met: "
            f"{'; '.join(met) or 'none'}. **Not met**: {'; '.join(missed) or 'none'}.")
    if deformed is not None:
        beats = _beats(proposed, deformed, seeds)
        lost = [text for text, ok, _ in beats if not ok]
        won = [firm for _, ok, firm in beats if ok]
        line += (f" Proposed's median beats deformed's on {len(won)} of {len(beats)} "
                 "metric/reference pairs" + (f"; **not** on {'; '.join(lost)}." if lost
                                              else ": every metric."))
        if seeds is not None:
            firm = sum(won)
            line += (f" The seeds settle {firm} of the {len(won)} it wins (their ranges do "
                     "not overlap)" + ("." if firm == len(won) else
                                       "; the rest are not settled."))
    return line


def verdict_line(report):
    """The demo's verdict: the clean-pass rule (``metrics.verdict``: holes and extras each
    at most CLEAN_RATE of the mesh's hits) on its evaluation poses, against the mesh."""
    m = report["vs_true"]
    poses = f"{report['poses']} {'unseen ' if report['unseen_poses'] else ''}poses"
    return (f"Verdict against the mesh on the {poses} (clean: holes and extras each at most "
            f"{percent(CLEAN_RATE)} of the mesh's hits): **{verdict(m)}** (holes "
            f"{percent(m.get('false_negative_rate'))}, extras "
            f"{percent(m.get('false_positive_rate'))}).")


def exact_speed(report):
    """The exact path's rays/s of an evaluation report, "n/a" without it."""
    exact = report["timings"].get("exact_rays_per_s")
    return "n/a" if exact is None else f"{exact:,.0f} rays/s"


def exr_passes(report):
    """The pass names of the demo's multilayer EXR: the compositor's, AO, Shadow and Shaded
    where the report has them."""
    names = list(COMPOSITOR_PASSES)
    return names + ([*SECONDARY_COMPOSITOR, *SHADED_COMPOSITOR] if "secondary" in report
                    else [])


def demo_markdown(report, command):
    """The demo's report: what ran, the metrics against both references (the AO and shadow
    errors where it has them), timings, figures."""
    t = report["timings"]
    return "\n".join([
        f"# VDNIF demo: {report['object']}",
        "",
        f"Command: `{command}`",
        "",
        f"Variant `{report['variant']}` trained on {report['train_poses']} "
        f"{'pose of a static scene' if report['mode'] == 'static' else 'random poses'} "
        f"({report['dataset_rays']:,} rays, {report['dataset_segments']:,} segments) at voxel "
        f"resolution {report['resolution']}, evaluated on {report['poses']} "
        f"{'unseen ' if report['unseen_poses'] else ''}poses from orbit cameras at "
        f"{report['width']}x{report['height']}. False negatives are reference hits the "
        "prediction misses (holes), false positives prediction hits the reference misses "
        "(extras), both as shares of the reference's hits.",
        *([f"Variant choice: {report['variant_note']}."] if report.get("variant_note") else []),
        "",
        metrics_table([(report["variant"], report["vs_true"], report["vs_embedded"])]),
        "",
        verdict_line(report),
        "",
        "| timing | value |",
        "| --- | --- |",
        f"| training | {value(t['train_s'], 3)} s, {t['train_steps']} steps, "
        f"{t['train_samples_per_s']:,.0f} samples/s |",
        f"| neural render (walk + network) | {speed_line(report)} |",
        f"| {EXACT_PATH}, same rays | {exact_speed(report)} |",
        f"| per-pose preparation (deform corners + entry BVH) | "
        f"{t['prepare_pose_s'] * 1e3:.1f} ms |",
        f"| model file | {report['model_bytes']:,} bytes |",
        "",
        f"{EMBREE_NOTE}; where the network is faster than a BVH and where it is not is "
        "measured there too.",
        "",
        "![reference, predicted, error per pass](figure-vs-true.png)",
        "",
        "The first view's passes are in `passes/`: `passes.exr`, a multilayer EXR of "
        f"{', '.join(exr_passes(report))} (in Blender's Compositor, an Image node opens "
        "it with one output per pass), and a PNG per pass.",
        "",
        "![speed and accuracy](speed-accuracy.png)",
        "",
        "The presets' points come from the bench sweep on the arm scene "
        "(docs/performance.md, 'Speed/accuracy sweep'), this demo's from its own scene and "
        "machine load: compare them loosely.",
        "",
        *secondary_section(report),
        *([f"![training loss per task]({pathlib.Path(report['training_plot']).name})", "",
           "Each task's training loss (solid) and its loss on the held-out training poses "
           "(dashed) over the steps, log scale.", ""] if report.get("training_plot") else []),
    ])


def write_section(path, key, title, body, preamble):
    """Rewrites the section ``key`` of the markdown file ``path`` (between its markers) with
    heading ``title`` and the lines ``body``, keeping every other section; appends it (to
    ``preamble`` for a new file) when absent."""
    path = pathlib.Path(path)
    start, end = f"<!-- {key} -->", f"<!-- end {key} -->"
    section = "\n".join([start, f"## {title}", "", *body, end])
    text = path.read_text() if path.exists() else preamble
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    text = pattern.sub(lambda _: section, text) if pattern.search(text) else (
        text.rstrip("\n") + "\n\n" + section)
    write_text_atomic(path, text + ("" if text.endswith("\n") else "\n"), "markdown file",
                      "markdown")
