"""The crossover: for each classical baseline, at each image size and thread setting, the
triangle count at which a neural pose (preparation + render) costs as much as the classical
pose (Blender's evaluation, reading the vertices, refit or build, casts), with the bytes of
each mesh beside it. Works on ``compare_paths`` results alone (no bpy, no timing).

The neural pose does not depend on the triangle count (its cost is the voxels' and the
rays'), but each mesh needs a model trained on it, so every mesh of the sweep has its own
neural figure. The crossing is found on the Suzanne sweep (one mesh subdivided, so its
sizes differ by a factor 4): between the two sweep meshes where neural / classical crosses
1, by linear interpolation of log(neural / classical) in log(triangles), which is exact
where both pose totals follow power laws of the triangle count. Other meshes (the bunny)
are reported as points: their ratio at their own size.
"""

import math

from ..text import percent
from .baselines import BASELINES
from .side_by_side_report import SHORT, pose_total, setting

PREVIEW = 64                # the preview's image size, square


def crossings(points):
    """[(triangles, +1 | -1)] where neural / classical crosses 1 along ``points``, a list of
    (triangles, neural ms, classical ms) sorted by triangles: +1 where the neural pose
    becomes the cheaper with more triangles, -1 where it stops being. Between two points
    log(ratio) is linear in log(triangles); a point whose ratio is exactly 1 is a crossing."""
    found = []
    logs = [(math.log(t), math.log(n / c)) for t, n, c in points]
    for (x0, y0), (x1, y1) in zip(logs, logs[1:]):
        if y0 != 0 and y1 != 0 and (y0 > 0) != (y1 > 0):
            found.append((math.exp(x0 + (x1 - x0) * y0 / (y0 - y1)), 1 if y0 > 0 else -1))
    for index, (_, y) in enumerate(logs):
        if y == 0:
            after = logs[index + 1][1] if index + 1 < len(logs) else -logs[index - 1][1]
            found.append((points[index][0], 1 if after < 0 else -1))
    return sorted(found)


SWEEP = "suzanne-"          # the scene names of the sweep: one mesh at several subdivisions


def crossover(results, sweep=SWEEP):
    """{"rows": one per baseline, image size and thread setting: where the neural pose
    becomes cheaper ("triangles", None where it does not cross inside the sweep, "text"
    saying why), the sweep's points and the other meshes' ratios; "bytes": one per mesh}.
    The sweep is the results whose scene name starts with ``sweep``."""
    groups = sorted({(r["width"], r["height"], setting(r)) for r in results},
                    key=lambda g: (-g[0] * g[1], -g[2]))
    rows = []
    for width, height, threads in groups:
        chosen = sorted((r for r in results if (r["width"], r["height"], setting(r))
                         == (width, height, threads)), key=lambda r: r["triangles"])
        swept = [r for r in chosen if r.get("scene", "").startswith(sweep)]
        others = [r for r in chosen if r not in swept]
        for baseline in BASELINES:
            points = [(r["triangles"], pose_total(r, "neural"), pose_total(r, baseline))
                      for r in swept]
            withheld = [r["object"] for r, (_, n, _) in zip(swept, points) if n is None]
            points = [p for p in points if p[1] is not None]
            triangles, text = _where(points, withheld)
            rows.append({
                "width": width, "height": height, "threads": threads, "baseline": baseline,
                "triangles": triangles, "text": text,
                "points": [{"triangles": t, "neural_ms": n, "classical_ms": c}
                           for t, n, c in points],
                "others": [{"object": r["object"], "triangles": r["triangles"],
                            "ratio": _ratio(r, baseline)} for r in others]})
    return {"rows": rows, "bytes": _bytes(results)}


def _where(points, withheld):
    """(triangles where the neural pose becomes and stays cheaper, or None; the text)."""
    if len(points) < 2:
        reason = (f"no neural speed on {', '.join(withheld)}" if withheld
                  else "fewer than two meshes in the sweep")
        return None, f"n/a ({reason})"
    found = crossings(points)
    last = points[-1]
    if not found:
        if last[1] < last[2]:
            return None, f"neural cheaper on the whole sweep ({points[0][0]:,} and up)"
        return None, f"classical cheaper on the whole sweep (up to {last[0]:,})"
    described = ", ".join(f"{'from' if way > 0 else 'until'} {t:,.0f}" for t, way in found)
    triangles = found[-1][0] if found[-1][1] > 0 else None
    return triangles, f"neural cheaper {described}"


def _ratio(result, baseline):
    neural, classical = pose_total(result, "neural"), pose_total(result, baseline)
    return None if neural is None else neural / classical


def _bytes(results):
    """One row per mesh: model bytes against mesh and mesh + each baseline's BVH bytes."""
    meshes = {r["object"]: r for r in sorted(results, key=lambda r: r["triangles"])}
    return [{"object": name, "triangles": r["triangles"], **r["bytes"]}
            for name, r in meshes.items()]


def crossover_markdown(data, results, command=None, machine=None, plot=None,
                       sweep="the Suzanne sweep"):
    """Markdown lines of a crossover (``crossover``) and the results it came from; ``sweep``
    names the meshes it was interpolated on."""
    lines = [f"Command: `{command}`", ""] if command else []
    lines += [machine, ""] if machine else []
    groups = list(dict.fromkeys((row["width"], row["height"], row["threads"])
                                for row in data["rows"]))
    heads = [f"{w}x{h}, {t} thread setting" for w, h, t in groups]
    lines += ["Triangles at which the neural pose (preparation + render) becomes cheaper than "
              "each classical pose (evaluation, read, refit or build, casts), interpolated "
              f"on {sweep} in log-log; other meshes as neural / classical at their "
              "size (below 1: neural cheaper).", "",
              "| baseline | " + " | ".join(heads) + " |", "|---" * (len(groups) + 1) + "|"]
    for baseline in BASELINES:
        cells = []
        for group in groups:
            row = next(r for r in data["rows"] if r["baseline"] == baseline
                       and (r["width"], r["height"], r["threads"]) == group)
            cells.append("; ".join([f"**{row['text']}**"] + [
                f"{o['object']} {'n/a' if o['ratio'] is None else format(o['ratio'], '.3g')}"
                for o in row["others"]]))
        lines.append(f"| {SHORT[baseline]} | " + " | ".join(cells) + " |")
    lines += ["", *_totals_table(results, groups), *_bytes_table(data["bytes"])]
    if plot:
        lines += [f"![pose totals and bytes against triangles]({plot})", ""]
    return lines


def _totals_table(results, groups):
    lines = ["Pose totals, milliseconds (median over repeats), and each model's hit IoU, "
             "false negatives and false positives against the true reference.", "",
             "| mesh | image, threads | " + " | ".join(SHORT[n] for n in ("neural", *BASELINES))
             + " | model: hit IoU, FN / FP |", "|---" * (len(BASELINES) + 4) + "|"]
    for result in sorted(results, key=lambda r: r["triangles"]):
        group = (result["width"], result["height"], setting(result))
        if group not in groups:
            continue
        totals = [pose_total(result, name) for name in ("neural", *BASELINES)]
        network = result["network"]
        model = ("none" if network["hit_iou"] is None else
                 f"{network['hit_iou']:.4f}, {percent(network['false_negative_rate'])} / "
                 f"{percent(network['false_positive_rate'])}")
        lines.append(f"| {result['object']} ({result['triangles']:,}) | {group[0]}x{group[1]}, "
                     f"{group[2]} | " + " | ".join("n/a" if t is None else f"{t:.1f}"
                                                   for t in totals) + f" | {model} |")
    return lines + [""]


def _bytes_table(meshes):
    lines = ["Bytes: the model against the mesh (float32 vertices, int32 triangles) + each "
             "baseline's BVH.", "",
             "| mesh | model | mesh | " + " | ".join(f"{SHORT[b]} BVH" for b in BASELINES)
             + " | " + " | ".join(f"model / (mesh + {SHORT[b]} BVH)" for b in BASELINES)
             + " |", "|---" * (2 * len(BASELINES) + 3) + "|"]
    for mesh in meshes:
        lines.append(f"| {mesh['object']} ({mesh['triangles']:,}) | {mesh['model']:,} | "
                     f"{mesh['mesh']:,} | "
                     + " | ".join(f"{mesh['bvh'][b]:,}" for b in BASELINES) + " | "
                     + " | ".join(f"{mesh['model_over_mesh_and_bvh'][b]:.3g}"
                                  for b in BASELINES) + " |")
    return lines + [""]
