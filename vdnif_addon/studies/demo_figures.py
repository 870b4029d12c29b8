"""The demo's figures for a reader without the report: reference | prediction | error per pass
with row and column titles and colour bars scaled to the data, the AO and shadow passes the
same way, and the speed/accuracy plot with the presets marked. Drawn with matplotlib (a
study's, never the extension's)."""

import json
import pathlib

import numpy as np

from ..inference.evaluation import distance_range
from ..inference.images import display
from ..presets import PRESET_ERROR, PRESET_NAMES, load_presets
from ..safe_io import atomic_path
from ..text import EXACT_PATH

MISS = np.array([0.16, 0.16, 0.17])       # no hit in a reference or a prediction: dark
ERROR_MISS = np.array([0.93, 0.93, 0.93])  # neither hits, in an error: the page's grey
ONE_SIDE = np.array([0.0, 0.85, 0.95])    # only one of reference and prediction hits
COLUMNS = ("Reference: exact cast of the deformed mesh", "Prediction: the network",
           "Error of the prediction")
SWEEP = pathlib.Path(__file__).resolve().parents[2] / "docs" / "bench" / "bench.json"
"""The bench sweep the presets were derived from (in the repository, not the extension)."""
ERROR_PERCENTILE = 99
"""An error colour bar ends at this percentile of the pixels' errors (a few outliers would
otherwise darken the rest); its label says where it ends."""


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    return pyplot


def _save(figure, path):
    pyplot = _pyplot()
    with atomic_path(path, "figure") as temporary:
        figure.savefig(temporary, dpi=100)
    pyplot.close(figure)
    return pathlib.Path(path)


def _error_scale(values):
    """The top of an error colour bar: the ERROR_PERCENTILE of ``values`` (> 0)."""
    if not len(values):
        return 1.0
    top = float(np.percentile(values, ERROR_PERCENTILE))
    return top if top > 0 else max(float(values.max()), 1e-9)


def _coloured(values, hit, cmap, vmin, vmax):
    """(R, 3) colours of ``values`` on a colour map where ``hit``, MISS elsewhere."""
    from matplotlib import colormaps

    x = np.clip((values - vmin) / max(vmax - vmin, 1e-30), 0, 1)
    rgb = colormaps[cmap](x)[:, :3]
    return np.where(hit[:, None], rgb, MISS)


def _bar(figure, cax, cmap, vmin, vmax, label):
    """A colour bar in its own axes ``cax`` (a narrow column of the grid)."""
    from matplotlib import cm, colors

    cax.set_visible(True)
    bar = figure.colorbar(cm.ScalarMappable(colors.Normalize(vmin, vmax), cmap), cax=cax)
    bar.set_label(label, fontsize=8)
    bar.ax.tick_params(labelsize=7)
    return bar


def _show(ax, rgb, height, width):
    ax.imshow(np.asarray(rgb, np.float32).reshape(height, width, 3), interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])


def _grid(rows, height, width, title):
    """(figure, images (rows, 3), bars (rows, 2)): the reference, prediction and error
    images with the column titles and ``title`` over them, a colour bar's column after the
    prediction (shared with the reference) and after the error, hidden until used."""
    pyplot = _pyplot()
    side = 3.0
    figure, axes = pyplot.subplots(
        rows, 5, figsize=(3 * side + 1.8, rows * side * height / width + 1.1),
        layout="constrained", squeeze=False,
        gridspec_kw={"width_ratios": [1, 1, 0.05, 1, 0.05]})
    images, bars = axes[:, [0, 1, 3]], axes[:, [2, 4]]
    for ax in bars.ravel():
        ax.set_visible(False)
    for ax, text in zip(images[0], COLUMNS):
        ax.set_title(text, fontsize=9)
    figure.suptitle(f"{title}\nEach error's bar ends at the {ERROR_PERCENTILE}th percentile "
                    "of that error; cyan: only one of reference and prediction hits",
                    fontsize=10)
    return figure, images, bars


def _one_side_note(ax, count, more=""):
    ax.set_xlabel(more + (f"hit by only one: {count} pixels" if count else
                          "both hit the same pixels"), fontsize=8)


def _nothing(ax, height, width, only, text):
    """An error panel with nothing to compare: the pixels only one hits, and ``text``."""
    _show(ax, np.where(only[:, None], ONE_SIDE, ERROR_MISS), height, width)
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})


def comparison_figure(path, reference, predicted, height, width, object_size, title):
    """Writes the reference | prediction | error figure of one view (``Passes`` of its
    reference and prediction, distances in local units, ``object_size`` local units to one
    object unit): rows normal, albedo, distance, material; the reference and the prediction
    share one distance colour bar; each error has its own bar scaled to the data (an albedo
    or material that is one value on every hit has nothing to predict and says so).
    Returns the path."""
    figure, axes, bars = _grid(4, height, width, title)
    both, only = reference.hit & predicted.hit, reference.hit ^ predicted.hit
    near, far = (v / object_size for v in distance_range(reference, predicted))
    shown = [display(p, height, width, (0.0, 1.0)) for p in (reference, predicted)]

    def error_rgb(values, vmax):
        rgb = _coloured(values, both, "magma", 0.0, vmax)
        return np.where(only[:, None], ONE_SIDE, np.where(both[:, None], rgb, ERROR_MISS))

    cosine = np.clip((predicted.normal * reference.normal).sum(1), -1, 1)
    errors = {"normal": (np.degrees(np.arccos(cosine)), "normal error (deg)"),
              "albedo": (np.abs(predicted.albedo - reference.albedo).max(1),
                         "albedo error (largest channel)"),
              "distance": (np.abs(predicted.distance - reference.distance) / object_size,
                           "distance error (object units)")}
    one_value = {"albedo": np.ptp(reference.albedo[reference.hit], axis=0).max(initial=0) == 0,
                 "material": len(np.unique(reference.material[reference.hit])) <= 1}
    for row, name in enumerate(("normal", "albedo", "distance", "material")):
        axes[row, 0].set_ylabel(name.title(), fontsize=10)
        for column, (passes, images) in enumerate(zip((reference, predicted), shown)):
            if name == "distance":
                rgb = _coloured(passes.distance / object_size, passes.hit, "viridis_r", near,
                                far)
            else:
                rgb = np.where(passes.hit[:, None], images[name].reshape(-1, 3), MISS)
            _show(axes[row, column], rgb, height, width)
        if name == "distance":
            _bar(figure, bars[row, 0], "viridis_r", near, far,
                 "distance (object units),\none scale for both")
        ax = axes[row, 2]
        if one_value.get(name):
            _nothing(ax, height, width, only, f"one {name} on every hit:\nnothing to predict")
            _one_side_note(ax, int(only.sum()))
            continue
        if name == "material":
            wrong = both & (predicted.material != reference.material)
            rgb = np.where(wrong[:, None], [0.9, 0.1, 0.1], [0.25, 0.25, 0.25])
            rgb = np.where(only[:, None], ONE_SIDE, np.where(both[:, None], rgb, ERROR_MISS))
            _show(ax, rgb, height, width)
            _one_side_note(ax, int(only.sum()), f"red: wrong slot, {int(wrong.sum())} "
                                                "pixels; ")
            continue
        values, label = errors[name]
        vmax = _error_scale(values[both])
        _show(ax, error_rgb(values, vmax), height, width)
        _bar(figure, bars[row, 1], "magma", 0.0, vmax, label)
        _one_side_note(ax, int(only.sum()))
    return _save(figure, path)


def secondary_figure(path, reference, predicted, height, width, title):
    """Writes the AO and shadow figure of one view (``SecondaryPasses`` of the reference
    and the prediction): reference | prediction | error, AO on one 0..1 colour bar and its
    error on a bar scaled to the data, shadow lit / shadowed and where they disagree.
    Returns the path."""
    from matplotlib.patches import Patch

    figure, axes, bars = _grid(2, height, width, title)
    both, only = reference.hit & predicted.hit, reference.hit ^ predicted.hit
    axes[0, 0].set_ylabel("AO", fontsize=10)
    axes[1, 0].set_ylabel("Shadow", fontsize=10)
    for column, passes in enumerate((reference, predicted)):
        _show(axes[0, column], _coloured(passes.ao, passes.hit, "cividis", 0.0, 1.0), height,
              width)
        lit = np.where(passes.lit[:, None], [0.98, 0.85, 0.35], [0.15, 0.2, 0.45])
        _show(axes[1, column], np.where(passes.hit[:, None], lit, MISS), height, width)
    _bar(figure, bars[0, 0], "cividis", 0.0, 1.0, "unoccluded share\n(1: open, 0: enclosed)")
    difference = np.abs(predicted.ao - reference.ao)
    vmax = _error_scale(difference[both])
    rgb = np.where(both[:, None], _coloured(difference, both, "magma", 0.0, vmax), ERROR_MISS)
    _show(axes[0, 2], np.where(only[:, None], ONE_SIDE, rgb), height, width)
    _bar(figure, bars[0, 1], "magma", 0.0, vmax, "AO error (share)")
    _one_side_note(axes[0, 2], int(only.sum()))
    false_lit, false_shadow = both & predicted.lit & ~reference.lit, \
        both & ~predicted.lit & reference.lit
    rgb = np.where(false_lit[:, None], [0.9, 0.1, 0.1],
                   np.where(false_shadow[:, None], [0.2, 0.4, 1.0], [0.25, 0.25, 0.25]))
    rgb = np.where(only[:, None], ONE_SIDE, np.where(both[:, None], rgb, ERROR_MISS))
    _show(axes[1, 2], rgb, height, width)
    axes[1, 1].legend(handles=[Patch(color=(0.98, 0.85, 0.35), label="lit"),
                               Patch(color=(0.15, 0.2, 0.45), label="shadowed")],
                      loc="lower right", fontsize=7)
    axes[1, 2].legend(handles=[
        Patch(color=(0.9, 0.1, 0.1), label=f"falsely lit ({int(false_lit.sum())})"),
        Patch(color=(0.2, 0.4, 1.0), label=f"falsely shadowed ({int(false_shadow.sum())})"),
        Patch(color=(0.25, 0.25, 0.25), label="agree")], loc="lower right", fontsize=7)
    _one_side_note(axes[1, 2], int(only.sum()))
    return _save(figure, path)


def sweep_points(path=SWEEP):
    """[(rays/s, error)] of the bench sweep's points that have both (``presets.PRESET_ERROR``),
    empty where the file is missing (outside the repository)."""
    try:
        points = json.loads(pathlib.Path(path).read_text())
    except (OSError, ValueError):
        return []
    return [(p["render_rays_per_s"], p[PRESET_ERROR]) for p in points
            if p.get("render_rays_per_s") and p.get(PRESET_ERROR) is not None]


def speed_accuracy_plot(path, report, presets=None, sweep=None):
    """Writes the speed/accuracy plot: rays/s against the distance error (object units,
    against the true reference), the bench sweep's points with the presets marked, this
    demo's model, and the exact path's rays/s of this run as a line (its error is 0).
    Returns the path."""
    pyplot = _pyplot()
    presets = load_presets() if presets is None else presets
    sweep = sweep_points() if sweep is None else sweep
    figure, ax = pyplot.subplots(figsize=(7.5, 5.4), layout="constrained")
    if sweep:
        ax.scatter(*zip(*sweep), s=18, color="0.6", label="bench sweep (arm scene)", zorder=2)
    for index, name in enumerate(PRESET_NAMES):
        if name not in presets:         # dropped by bench: no point of its own to mark
            continue
        measured = presets[name]["measured"]
        speed, error = measured.get("render_rays_per_s"), measured.get(PRESET_ERROR)
        if speed and error is not None:
            ax.scatter([speed], [error], s=70, marker="D", color=f"C{index}", zorder=3,
                       edgecolor="black", label=f"preset {name.title()} (bench, arm)")
            ax.annotate(name.title(), (speed, error), xytext=(6, 4),
                        textcoords="offset points", fontsize=9)
    timings, scene = report["timings"], report["object"]
    speed, error = timings.get("render_rays_per_s"), report["vs_true"].get("distance_mae")
    if speed and error is not None:
        ax.scatter([speed], [error], s=140, marker="*", color="C3", edgecolor="black",
                   zorder=4, label=f"this demo's model ({scene})")
    exact = timings.get("exact_rays_per_s")
    if exact:
        ax.axvline(exact, color="black", linestyle="--", linewidth=1,
                   label=f"{EXACT_PATH}, this demo: error 0")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("rays per second (higher is faster)")
    ax.set_ylabel("distance error against the mesh (object units, lower is better)")
    ax.set_title("Speed and accuracy: the presets, this demo, the exact path", fontsize=11)
    ax.grid(True, which="both", alpha=0.3)
    figure.legend(fontsize=7, loc="outside lower center", ncol=2)
    return _save(figure, path)


def demo_figures(out, report, view, height, width, object_size):
    """The demo's figures of its first evaluation view into folder ``out``: against the true
    and the embedded reference, the AO and shadow passes when the view has them, and the
    speed/accuracy plot; returns {name: path}."""
    out = pathlib.Path(out)
    pose = (f"{report['object']}, unseen pose 1 of {report['poses']}" if report["unseen_poses"]
            else f"{report['object']}, pose 1 of {report['poses']}")
    paths = {}
    for name, what in (("true", "the mesh"), ("embedded", "the voxel embedding")):
        paths[f"figure_vs_{name}"] = comparison_figure(
            out / f"figure-vs-{name}.png", view[name], view["predicted"], height, width,
            object_size, f"{pose}: the network against {what}")
    if "secondary" in view:
        shown = view["secondary"]
        paths["figure_secondary_vs_true"] = secondary_figure(
            out / "figure-secondary-vs-true.png", shown["true"], shown["predicted"], height,
            width, f"{pose}: ambient occlusion and shadow against the mesh")
    paths["speed_accuracy"] = speed_accuracy_plot(out / "speed-accuracy.png", report)
    return paths
