"""Markdown for people: the demo's report, the tables of the experiments and benchmarks, and
the sections that each command rewrites in a shared document."""

import pathlib
import re

from .safe_io import write_text_atomic

# The paper's proposed figures (DESIGN section 10), the accuracy goal of the deformed scenes.
PAPER_PROPOSED = {"distance_mae": 0.039, "normal_error_deg": 11.8}


def value(number, digits=4):
    return "n/a" if number is None else f"{number:.{digits}g}"


def percent(share, digits=3):
    """A share in [0, 1] as a percentage, "n/a" for None."""
    return "n/a" if share is None else f"{100 * share:.{digits}g} %"


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


def common_pixels_line(labels, metrics):
    """What the errors of the compared models ``labels`` are taken over (DESIGN section
    10), from one of their compare_both results on the common pixel set."""
    counts = {name: metrics[f"vs_{name}"]["compared_rays"] for name in ("true", "embedded")}
    return (f"{', '.join(labels)}: distance, normal, albedo and material errors over the "
            f"same pixels, where all {len(labels)} models and the reference hit (the common "
            f"pixel set: {counts['true']:,} pixels against the true reference, "
            f"{counts['embedded']:,} against the embedded one); hit IoU and the false-"
            "negative and false-positive rates over every pixel, the rates as shares of the "
            "reference's hits.")


def speed_line(report):
    """The neural render's rays/s of an evaluation report, or n/a with the reason
    (metrics.speed_withheld: only models that predict hits have a speed)."""
    speed = report["timings"].get("render_rays_per_s")
    if speed is not None:
        return f"{speed:,.0f} rays/s"
    return f"n/a ({report['speed_withheld']})" if report.get("speed_withheld") else "n/a"


def goal_line(metrics):
    """Whether metrics against the embedded reference reach the paper's proposed figures."""
    reached = all(metrics[key] is not None and metrics[key] <= goal
                  for key, goal in PAPER_PROPOSED.items())
    return (f"Goal (paper's proposed: distance MAE <= {PAPER_PROPOSED['distance_mae']}, normal "
            f"error <= {PAPER_PROPOSED['normal_error_deg']} deg, against the embedded "
            f"reference): **{'reached' if reached else 'not reached'}**.")


def demo_markdown(report, command, figure_name):
    """The demo's report: what ran, the metrics against both references, timings, figure."""
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
        goal_line(report["vs_embedded"]),
        "",
        "| timing | value |",
        "| --- | --- |",
        f"| training | {value(t['train_s'], 3)} s, {t['train_steps']} steps, "
        f"{t['train_samples_per_s']:,.0f} samples/s |",
        f"| neural render (walk + network) | {speed_line(report)} |",
        f"| per-pose preparation (deform corners + entry BVH) | "
        f"{t['prepare_pose_s'] * 1e3:.1f} ms |",
        f"| model file | {report['model_bytes']:,} bytes |",
        "",
        f"![reference, predicted, error per pass]({figure_name})",
        "",
        "Rows: normal, albedo, distance, material. Columns: the true reference (Blender's "
        "deformed mesh), the prediction, the error (distance error bright at 0.05 object "
        "units, normal error bright at 45 deg; white where only one of them hits).",
        "",
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
    write_text_atomic(path, text + ("" if text.endswith("\n") else "\n"), "markdown file")
