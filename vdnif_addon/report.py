"""Markdown for people: the demo's report, the tables of the experiments and benchmarks, and
the sections that each command rewrites in a shared document."""

import pathlib
import re

# The paper's proposed figures (DESIGN section 10), the accuracy goal of the deformed scenes.
PAPER_PROPOSED = {"distance_mae": 0.039, "normal_error_deg": 11.8}


def value(number, digits=4):
    return "n/a" if number is None else f"{number:.{digits}g}"


def metrics_table(rows):
    """A markdown table of (label, vs_true metrics, vs_embedded metrics) rows."""
    lines = ["| | reference | distance MAE (object units) | normal error (deg) | hit IoU "
             "| albedo PSNR (dB) | material accuracy |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for label, vs_true, vs_embedded in rows:
        for name, m in (("true", vs_true), ("embedded", vs_embedded)):
            lines.append(f"| {label} | {name} | {value(m['distance_mae'])} | "
                         f"{value(m['normal_error_deg'], 3)} | {value(m['hit_iou'])} | "
                         f"{value(m.get('albedo_psnr'), 3)} | "
                         f"{value(m.get('material_accuracy'), 3)} |")
    return "\n".join(lines)


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
        f"Variant `{report['variant']}` trained on {report['train_poses']} random poses "
        f"({report['dataset_rays']:,} rays, {report['dataset_segments']:,} segments) at voxel "
        f"resolution {report['resolution']}, evaluated on {report['poses']} "
        f"{'unseen ' if report['unseen_poses'] else ''}poses from orbit cameras at "
        f"{report['width']}x{report['height']}.",
        "",
        metrics_table([(report["variant"], report["vs_true"], report["vs_embedded"])]),
        "",
        goal_line(report["vs_embedded"]),
        "",
        "| timing | value |",
        "| --- | --- |",
        f"| training | {value(t['train_s'], 3)} s, {t['train_steps']} steps, "
        f"{t['train_samples_per_s']:,.0f} samples/s |",
        f"| neural render (walk + network) | {t['render_rays_per_s']:,.0f} rays/s |",
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
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + ("" if text.endswith("\n") else "\n"))
