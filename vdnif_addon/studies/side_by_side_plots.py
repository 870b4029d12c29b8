"""The side-by-side plots, from ``compare_paths`` results alone (no bpy, no timing): rays/s and
pose totals against triangle count, model bytes against mesh + BVH bytes, and the crossover
figure (pose totals per image size and thread setting, where the neural pose costs as much as
each classical one, bytes beside them)."""

import pathlib

from ..safe_io import atomic_path
from .baselines import BASELINES

PLOTS = {"speed": "side-by-side-speed.png", "bytes": "side-by-side-bytes.png"}
SHORT = {"neural": "neural", "bvhtree": "BVHTree (Python loop)", "warp": "Warp refit",
         "embree_refit": "Embree refit", "embree_rebuild": "Embree rebuild"}
STYLES = {"neural": ("C3", "o"), "bvhtree": ("C0", "s"), "warp": ("C2", "^"),
          "embree_refit": ("C1", "D"), "embree_rebuild": ("C4", "v")}
# A thread setting's line: the largest solid, the others dashed, then dotted.
LINES = ("-", "--", ":", "-.")


def pose_total(result, name):
    """Milliseconds per pose of a path (preparation + render, or evaluation, read, refit or
    build + casts), None where not measured or withheld."""
    median = result["median"]
    keys = (("neural_pose_s", "neural_render_s") if name == "neural"
            else (f"{name}_pose_s", f"{name}_cast_s"))
    if any(median.get(key) is None for key in keys):
        return None
    return 1e3 * sum(median[key] for key in keys)


def setting(result):
    """The thread setting a result was measured at."""
    return result["threads"]["setting"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    return pyplot


def _save(figure, path, pyplot):
    figure.tight_layout()
    with atomic_path(path, "plot") as temporary:
        figure.savefig(temporary, dpi=120)
    pyplot.close(figure)


def write_plots(results, folder):
    """Writes the speed and bytes plots of ``results`` (those at the first result's image
    size) into ``folder``; returns {"speed" | "bytes": path}. The Suzanne sweep (one mesh
    subdivided) is drawn as lines, one line style per thread setting, any other mesh as
    hollow markers at its triangle count."""
    pyplot = _pyplot()
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    size = (results[0]["width"], results[0]["height"])
    results = sorted((r for r in results if (r["width"], r["height"]) == size),
                     key=lambda r: r["triangles"])
    settings = sorted({setting(r) for r in results}, reverse=True)
    paths = {name: folder / file for name, file in PLOTS.items()}

    figure, axes = pyplot.subplots(1, 2, figsize=(12, 5))
    for name in ("neural", *BASELINES):
        for index, threads in enumerate(settings):
            chosen = [r for r in results if setting(r) == threads]
            label = f"{SHORT[name]}, {threads} thread setting"
            for ax, figure_of in ((axes[0], lambda r, n=name: r["rays_per_s"][n]),
                                  (axes[1], lambda r, n=name: pose_total(r, n))):
                series(ax, chosen, figure_of, *STYLES[name], label, LINES[index % len(LINES)])
    for ax, label in ((axes[0], "rays/s (casts or neural render)"),
                      (axes[1], "pose total, ms (preparation + render)")):
        axes_style(ax, results, label)
    withheld = sorted({r["object"] for r in results if r["rays_per_s"]["neural"] is None})
    figure.suptitle(f"{size[0]}x{size[1]} rays per view, unseen poses, medians over repeats"
                    + (f"; neural n/a (no model that predicts hits) on {', '.join(withheld)}"
                       if withheld else ""), fontsize=9)
    _save(figure, paths["speed"], pyplot)

    figure, ax = pyplot.subplots(figsize=(7.5, 5))
    bytes_series(ax, _one_per_mesh(results))
    axes_style(ax, results, "bytes")
    _save(figure, paths["bytes"], pyplot)
    return paths


def bytes_series(ax, results):
    """Model bytes, mesh bytes and mesh + each baseline's BVH bytes against triangles."""
    series(ax, results, lambda r: r["bytes"]["model"], "C3", "o", "model")
    series(ax, results, lambda r: r["bytes"]["mesh"], "0.4", "x", "mesh alone")
    for name in BASELINES:
        series(ax, results, lambda r, n=name: r["bytes"]["mesh"] + r["bytes"]["bvh"][n],
               *STYLES[name], f"mesh + {SHORT[name]} BVH")


def _one_per_mesh(results):
    """One result per mesh (the bytes do not depend on the size or the thread setting)."""
    return list({r["object"]: r for r in results}.values())


def write_crossover_plot(crossover, results, path):
    """The crossover figure into ``path``: per image size (columns) and thread setting
    (rows) the pose totals against triangles, each crossover a vertical line in its
    baseline's colour, and the bytes beside the first row."""
    pyplot = _pyplot()
    sizes = sorted({(r["width"], r["height"]) for r in results}, reverse=True)
    settings = sorted({setting(r) for r in results}, reverse=True)
    figure, axes = pyplot.subplots(len(settings), len(sizes) + 1, squeeze=False,
                                   figsize=(5.5 * (len(sizes) + 1), 4.2 * len(settings)))
    ordered = sorted(results, key=lambda r: r["triangles"])
    for row, threads in enumerate(settings):
        for column, size in enumerate(sizes):
            ax = axes[row][column]
            chosen = [r for r in ordered if setting(r) == threads
                      and (r["width"], r["height"]) == size]
            for name in ("neural", *BASELINES):
                series(ax, chosen, lambda r, n=name: pose_total(r, n), *STYLES[name],
                       SHORT[name])
            for entry in crossover["rows"]:
                if (entry["threads"] == threads and (entry["width"], entry["height"]) == size
                        and entry["triangles"] is not None):
                    ax.axvline(entry["triangles"], color=STYLES[entry["baseline"]][0],
                               linestyle="--", linewidth=1)
            axes_style(ax, chosen, "pose total, ms")
            ax.set_title(f"{size[0]}x{size[1]}, {threads} thread setting (dashed: crossover)",
                         fontsize=9)
        ax = axes[row][len(sizes)]
        if row:                      # the bytes do not depend on the thread setting
            ax.axis("off")
            continue
        bytes_series(ax, _one_per_mesh(ordered))
        axes_style(ax, ordered, "bytes")
        ax.set_title("model bytes against mesh + BVH bytes", fontsize=9)
    _save(figure, pathlib.Path(path), pyplot)
    return pathlib.Path(path)


def _sweep(result):
    """Whether ``result`` belongs to the Suzanne subdivision sweep (drawn as a line)."""
    return result.get("scene", "").startswith("suzanne-")


def series(ax, results, figure_of, color, marker, label, linestyle="-"):
    """One path's figures against triangles: a line over the sweep, hollow markers for
    the other meshes; nothing where the figure is None."""
    points = [(r["triangles"], figure_of(r), _sweep(r)) for r in results
              if figure_of(r) is not None]
    sweep = [(t, v) for t, v, in_sweep in points if in_sweep]
    others = [(t, v) for t, v, in_sweep in points if not in_sweep]
    if sweep:
        ax.plot(*zip(*sweep), marker=marker, color=color, label=label, linestyle=linestyle)
    if others:
        ax.plot(*zip(*others), linestyle="none", marker=marker, color=color,
                markerfacecolor="none", label=None if sweep else label)


def axes_style(ax, results, label):
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("triangles (lines: Suzanne subdivided; hollow: other meshes)")
    ax.set_ylabel(label)
    for name, triangles in {r["object"]: r["triangles"] for r in results
                            if not _sweep(r)}.items():
        ax.axvline(triangles, linestyle=":", color="0.6", linewidth=0.8)
        ax.text(triangles, 1.0, f" {name}", rotation=90, fontsize=7, va="top", ha="right",
                transform=ax.get_xaxis_transform())
    ax.grid(True, which="major", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)
