"""What a ``side-by-side`` run reports: the markdown tables (one column per scene), the targets
it is held to, the plots (rays/s and pose totals against triangle count; model bytes against
mesh + BVH bytes) and its section of ``docs/performance.md``. Works on ``compare_paths``
results alone (JSON-ready dicts): no bpy, no timing."""

import pathlib

from ..inference.metrics import SPEED_MIN_HIT_IOU
from ..safe_io import atomic_path
from ..text import percent
from .baselines import BASELINES
from .report import write_section

SECTION = "side-by-side"
TITLE = "Side by side with the classical baselines"
PATHS = {"neural": "neural render (walk + network)",
         "bvhtree": "Blender `BVHTree`: rebuild, `ray_cast` loop",
         "warp": "Warp mesh BVH: refit, `mesh_query_ray` kernel",
         "embree": "Embree (`embreex`): scene rebuilt, `run`"}
SHORT = {"neural": "neural", "bvhtree": "BVHTree", "warp": "Warp refit", "embree": "Embree"}
PLOTS = {"speed": "side-by-side-speed.png", "bytes": "side-by-side-bytes.png"}

# The targets of the neural path (DESIGN section 10), set for 2 CPU cores.
TARGET_RAYS_PER_S = 0.5e6          # neural render, trained model, unseen poses, 256x256
TARGET_WALK = 1.3                  # deformed walk / static DDA walk, rest pose
TARGET_WALK_NETWORK = 1.05         # the same with the network over every walked segment
TARGET_PREPARE_S = 0.010           # per-pose preparation, set for the bunny at R 32
TARGET_PREPARE_RATIO = 0.05        # per-pose preparation / BVHTree rebuild, set for 1 M tris


def _targets():
    """(label, figure(result) -> value or None, format, goal(value) -> bool)."""
    return (
        (f"neural render >= {TARGET_RAYS_PER_S / 1e6:g} M rays/s",
         lambda r: r["rays_per_s"]["neural"], lambda v: f"{v / 1e6:.3g} M",
         lambda v: v >= TARGET_RAYS_PER_S),
        *((f"pose total below {SHORT[b]}'s (neural / {SHORT[b]} < 1)",
           lambda r, b=b: r["ratios"][f"pose_neural_over_{b}"], lambda v: f"{v:.3g}",
           lambda v: v < 1) for b in BASELINES),
        (f"walk: deformed / static DDA <= {TARGET_WALK}",
         lambda r: r["ratios"]["walk_deformed_over_static"], lambda v: f"{v:.3g}",
         lambda v: v <= TARGET_WALK),
        (f"walk + network: deformed / static DDA <= {TARGET_WALK_NETWORK}",
         lambda r: r["ratios"]["walk_and_network_deformed_over_static"],
         lambda v: f"{v:.3g}", lambda v: v <= TARGET_WALK_NETWORK),
        (f"per-pose preparation <= {TARGET_PREPARE_S * 1e3:g} ms (set for the bunny at R 32)",
         lambda r: r["median"]["neural_pose_s"], lambda v: f"{v * 1e3:.3g} ms",
         lambda v: v <= TARGET_PREPARE_S),
        (f"per-pose preparation <= {TARGET_PREPARE_RATIO:g}x the BVHTree rebuild (set for the "
         f"1 M mesh)", lambda r: r["ratios"]["prepare_neural_over_bvhtree"],
         lambda v: f"{v:.3g}", lambda v: v <= TARGET_PREPARE_RATIO),
    )


TARGETS = _targets()


def target_rows(result):
    """[(label, value text, met: True/False/None)] of one result; None where the figure is
    n/a (withheld or not run)."""
    rows = []
    for label, figure, text, goal in TARGETS:
        value = figure(result)
        rows.append((label, "n/a" if value is None else text(value),
                     None if value is None else bool(goal(value))))
    return rows


def _ratio_text(value, runs, subject="neural"):
    """A ratio that says which way it goes, with each repeat's value."""
    if value is None:
        return "n/a"
    way = (f"{subject} {1 / value:.3g}x faster" if value < 1
           else f"{subject} {value:.3g}x slower")
    return f"**{value:.3g}** ({way}; " + ", ".join(f"{v:.3g}" for v in runs) + ")"


def side_by_side_markdown(results, command=None, machine=None, plots=None):
    """Markdown lines of one or more ``compare_paths`` results, one column per scene:
    targets, speeds, ratios, steps, agreement of the baselines, models, bytes, settings.
    ``command`` is the command that measured them, ``machine`` a ``machine_text`` line, and
    ``plots`` {"speed" | "bytes": relative path} the plot files to show."""
    heads = " | ".join(f"{r['object']} ({r['triangles']:,} triangles)" for r in results)
    rule = "|---" * (len(results) + 1) + "|"

    def table(title, rows):
        return [title, "", f"| | {heads} |", rule,
                *(f"| {label} | " + " | ".join(cells) + " |" for label, cells in rows), ""]

    def ms(key):
        return [("n/a" if r["median"].get(key) is None else f"{1e3 * r['median'][key]:.1f}")
                for r in results]

    first = results[0]
    lines = []
    if command is not None:
        lines += [f"Command: `{command}`", ""]
    lines += [_what_is_timed(first), ""]
    if machine is not None:
        lines += [machine, ""]
    lines += _withheld_lines(results)
    lines += table("Targets (met / missed; n/a where the figure is withheld or not run).",
                   [(label, [f"{text}{_met(met)}" for text, met in cells])
                    for label, *cells in _transpose_targets(results)])
    speed_rows = [(f"{PATHS[name]}, rays/s ({_threads(first, name)})",
                   ["n/a" if r["rays_per_s"][name] is None else f"{r['rays_per_s'][name]:,.0f}"
                    for r in results]) for name in ("neural", *BASELINES)]
    total_rows = [("neural pose total: preparation + render", [
        "n/a" if r["median"].get("neural_render_s") is None else
        f"{1e3 * (r['median']['neural_pose_s'] + r['median']['neural_render_s']):.1f}"
        for r in results])]
    total_rows += [(f"{SHORT[b]} pose total: {'refit' if b == 'warp' else 'rebuild'} + casts",
                    [f"{1e3 * (r['median'][f'{b}_rebuild_s'] + r['median'][f'{b}_cast_s']):.1f}"
                     for r in results]) for b in BASELINES]
    lines += table("Speed: rays per second of the casts or the neural render, median over "
                   "repeats.", speed_rows)
    lines += table("Pose total, milliseconds per pose (Blender's evaluation included on "
                   "every side).", total_rows)
    ratio_rows = []
    for b in BASELINES:
        for kind, text in (("prepare", "per-pose preparation"), ("render", "render / casts"),
                           ("pose", "pose total")):
            name = f"{kind}_neural_over_{b}"
            ratio_rows.append((f"{text}: neural / {SHORT[b]}",
                               [_ratio_text(r["ratios"][name], r["ratio_runs"][name])
                                for r in results]))
    for name, text in (("walk_deformed_over_static", "walk: deformed / static DDA (rest pose)"),
                       ("walk_and_network_deformed_over_static",
                        "walk + network: deformed / static DDA (rest pose)")):
        ratio_rows.append((text, [_ratio_text(r["ratios"][name], r["ratio_runs"][name],
                                              "deformed walk") for r in results]))
    lines += table("Ratios, median over repeats of each repeat's ratio (each repeat's value "
                   "after the semicolon); below 1 the neural path (or the deformed walk) is "
                   "cheaper.", ratio_rows)
    lines += table("Steps, milliseconds per pose (or rest view): mean over the poses of one "
                   "repeat, median over repeats.",
                   [(label, ms(key)) for label, key in STEP_ROWS]
                   + [("walked segments (rest view)",
                       [f"{r['median']['walk_segments']:,.0f}" for r in results]),
                      ("segments the neural render evaluated (per pose)",
                       ["n/a" if r["median"].get("neural_segments") is None
                        else f"{r['median']['neural_segments']:,.0f}" for r in results])])
    lines += table("Hits of each baseline against the true reference (the project's float64-"
                   "refined Warp cast on the same deformed mesh), over the views of the first "
                   "repeat: rays whose hit differs, and the largest distance difference where "
                   "both hit (object units).",
                   [(SHORT[b], [_agreement_text(r["agreement"][b]) for r in results])
                    for b in BASELINES])
    lines += table("Models: the neural side's hit IoU against the true reference on the same "
                   "views decides whether it has speeds.", [
                       ("model", [f"`{r['network']['model']}` ({r['network']['variant']})"
                                  if r["network"]["model"] else "none" for r in results]),
                       ("hit IoU, false negatives / positives (vs true)",
                        [_iou_text(r["network"]) for r in results])])
    lines += _bytes_table(results, table)
    if plots:
        lines += [f"![rays/s and pose total against triangles]({plots['speed']})", "",
                  f"![model bytes against mesh + BVH bytes]({plots['bytes']})", ""]
    lines += table("Settings.", [
        ("resolution, occupied voxels",
         [f"{r['resolution']}, {r['occupied_voxels']:,}" for r in results]),
        ("poses x repeats, rays per view",
         [f"{r['poses']} x {r['repeats']}, {r['width']}x{r['height']}" for r in results]),
        ("DDA and deformed walk give the same cells",
         [_match_text(r) for r in results])])
    return lines


STEP_ROWS = (
    ("BVHTree: evaluate the mesh's modifiers", "bvhtree_evaluate_s"),
    ("BVHTree: `BVHTree.FromObject`", "bvhtree_build_s"),
    ("BVHTree: casts (`ray_cast` loop)", "bvhtree_cast_s"),
    ("Warp: evaluate the mesh's modifiers", "warp_evaluate_s"),
    ("Warp: read the evaluated vertices", "warp_read_s"),
    ("Warp: copy in + `refit`", "warp_refit_s"),
    ("Warp: casts (`mesh_query_ray` kernel)", "warp_cast_s"),
    ("Embree: evaluate the mesh's modifiers", "embree_evaluate_s"),
    ("Embree: read the evaluated vertices", "embree_read_s"),
    ("Embree: new scene, `TriangleMesh` (the binding's copy)", "embree_copy_s"),
    ("Embree: commit (BVH build)", "embree_commit_s"),
    ("Embree: casts (`run`)", "embree_cast_s"),
    ("neural: evaluate the corner helper's modifiers", "neural_evaluate_s"),
    ("neural: read corners + refit cells and entry BVH (`prepare_s`)", "neural_prepare_s"),
    ("neural: render (walk + network)", "neural_render_s"),
    ("neural render: walk (seconds inside the render)", "neural_walk_s"),
    ("neural render: network (seconds inside the render)", "neural_network_s"),
    ("rest view: deformed walk (`tracing.traverse.traverse`)", "deformed_walk_s"),
    ("rest view: static DDA walk (`tracing.static_grid.StaticGrid`)", "static_walk_s"),
    ("rest view: network over every walked segment", "all_segments_network_s"),
)


def _match_text(result):
    """Whether both walks gave the same (ray, cell) segments on every rest view, and where
    not, how many each walked (median per rest view)."""
    if result["segments_match"]:
        return "yes"
    median = result["median"]
    return (f"no, on some rest view; segments per rest view (median): "
            f"{median['deformed_walk_segments']:,.0f} deformed, "
            f"{median['walk_segments']:,.0f} static")


def _what_is_timed(result):
    return (
        f"Per repeat, each of {result['poses']} unseen poses (evaluation poses, disjoint from "
        "the model's training poses) is seen from an orbit camera of "
        f"{result['width']}x{result['height']} rays in the object's local space. Every "
        "classical baseline starts from Blender's evaluation of the pose (the object is "
        "tagged, then `evaluated_depsgraph_get()`): **BVHTree** rebuilds with "
        "`BVHTree.FromObject` and casts in a Python loop of `ray_cast` (no batch API); "
        "**Warp** reads the evaluated vertices (`foreach_get`), copies them into its mesh BVH "
        "built once on the rest triangles, refits it and casts with one `mesh_query_ray` "
        "kernel; **Embree** reads the vertices, builds a new robust scene (`embreex`: "
        "`EmbreeScene`, `TriangleMesh`, the commit on the first `run`) and casts with `run`, "
        "the rays split over two threads (`TriangleMesh` copies the mesh element by element "
        "through Python indexing: its 'copy' step is the binding's cost, the 'commit' step "
        "Embree's own build). The **neural** path re-evaluates the corner "
        "helper's modifiers, reads the deformed corners and refits the cells and the entry "
        "BVH (its preparation), then renders (`inference.neural_render.neural_passes`: walk "
        "+ network in waves, a ray stops at its first predicted hit). On the rest pose, the "
        "deformed walk (`tracing.traverse.traverse`) is timed against the static DDA walk "
        "(`tracing.static_grid.StaticGrid`) of the "
        "same rays, and the network over every walked segment is added to both. Each ratio "
        "is computed within one repeat from the per-pose means of both sides, timed "
        "alternately in one process after one untimed pass.")


def _withheld_lines(results):
    withheld = [r for r in results if r["speed_withheld"] is not None]
    if not withheld:
        return []
    return [f"Neural speeds n/a (only a trained model whose hit IoU against the true "
            f"reference reaches {SPEED_MIN_HIT_IOU} on these views has speeds):", "",
            *(f"- {r['object']}: {r['speed_withheld']}." for r in withheld), ""]


def _transpose_targets(results):
    per_result = [target_rows(r) for r in results]
    return [(label, *[(rows[i][1], rows[i][2]) for rows in per_result])
            for i, (label, _, _) in enumerate(per_result[0])]


def _met(met):
    return "" if met is None else (" (met)" if met else " (**missed**)")


def _threads(result, name):
    if name == "neural":
        return (f"torch's MLP on {result['threads']['torch']} thread(s), the Warp encoder and "
                "the walk on one each beside it")
    return f"{result['threads'][name]} thread(s)"


def _agreement_text(agreement):
    difference = agreement["max_distance_difference"]
    return (f"{agreement['differing_hits']} of {agreement['rays']:,} rays differ; "
            + ("no common hit" if difference is None else f"max {difference:.2g}"))


def _iou_text(network):
    if network["hit_iou"] is None:
        return "n/a"
    return (f"{network['hit_iou']:.4f}, {percent(network['false_negative_rate'])} / "
            f"{percent(network['false_positive_rate'])}")


def _bytes_table(results, table):
    rows = [("model", [f"{r['bytes']['model']:,}" for r in results]),
            ("mesh (float32 vertices + int32 triangles)",
             [f"{r['bytes']['mesh']:,}" for r in results])]
    for b in BASELINES:
        rows.append((f"{SHORT[b]} BVH", [f"{r['bytes']['bvh'][b]:,}" for r in results]))
        rows.append((f"model / (mesh + {SHORT[b]} BVH)",
                     [f"**{r['bytes']['model_over_mesh_and_bvh'][b]:.3g}**" for r in results]))
    first = results[0]["bytes"]
    notes = [f"- model: {first['model_source']}."]
    notes += [f"- {SHORT[b]} BVH: {first['bvh_source'][b]}." for b in BASELINES]
    return table("Bytes.", rows) + notes + [""]


def machine_text(machine):
    """One line naming the machine and the thread settings of a run (``side_by_side.
    machine``)."""
    return (f"Machine: {machine['cpu']}, {machine['cores']} cores available; load average "
            f"{machine['load_before']:.2f} before and {machine['load_after']:.2f} after the "
            f"run (other work on the machine slows every side alike only roughly: compare "
            f"ratios, not absolute times). OMP_NUM_THREADS={machine['omp_num_threads']}, torch "
            f"{machine['torch']} on {machine['torch_threads']} thread(s); Warp "
            f"{machine['warp']} on {machine['warp_device']} (a CPU launch runs on one "
            f"thread); Embree through embreex {machine['embreex']}; Blender "
            f"{machine['blender']}.")


def write_plots(results, folder):
    """Writes the speed and bytes plots of ``results`` into ``folder``; returns
    {"speed" | "bytes": path}. The Suzanne sweep (one mesh subdivided) is drawn as lines,
    any other mesh as hollow markers on a dotted line at its triangle count."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    results = sorted(results, key=lambda r: r["triangles"])
    paths = {name: folder / file for name, file in PLOTS.items()}
    styles = {"neural": ("C3", "o"), "bvhtree": ("C0", "s"), "warp": ("C2", "^"),
              "embree": ("C1", "D")}

    figure, axes = pyplot.subplots(1, 2, figsize=(12, 5))
    for name in ("neural", *BASELINES):
        for ax, figure_of in ((axes[0], lambda r, n=name: r["rays_per_s"][n]),
                              (axes[1], lambda r, n=name: _pose_total(r, n))):
            _series(ax, results, figure_of, *styles[name], SHORT[name])
    for ax, label in ((axes[0], "rays/s (casts or neural render)"),
                      (axes[1], "pose total, ms (preparation + render)")):
        _axes(ax, results, label)
    first = results[0]
    withheld = [r["object"] for r in results if r["rays_per_s"]["neural"] is None]
    figure.suptitle(f"{first['width']}x{first['height']} rays per view, unseen poses, "
                    "medians over repeats" + (f"; neural n/a (no model that predicts hits) "
                                              f"on {', '.join(withheld)}" if withheld else ""),
                    fontsize=9)
    figure.tight_layout()
    with atomic_path(paths["speed"], "plot") as temporary:
        figure.savefig(temporary, dpi=120)
    pyplot.close(figure)

    figure, ax = pyplot.subplots(figsize=(7.5, 5))
    _series(ax, results, lambda r: r["bytes"]["model"], "C3", "o", "model")
    _series(ax, results, lambda r: r["bytes"]["mesh"], "0.4", "x", "mesh alone")
    for name in BASELINES:
        _series(ax, results, lambda r, n=name: r["bytes"]["mesh"] + r["bytes"]["bvh"][n],
                *styles[name], f"mesh + {SHORT[name]} BVH")
    _axes(ax, results, "bytes")
    figure.tight_layout()
    with atomic_path(paths["bytes"], "plot") as temporary:
        figure.savefig(temporary, dpi=120)
    pyplot.close(figure)
    return paths


def _pose_total(result, name):
    """Milliseconds per pose of a path (preparation + render, or rebuild / refit + casts),
    None where not measured or withheld."""
    median = result["median"]
    keys = (("neural_pose_s", "neural_render_s") if name == "neural"
            else (f"{name}_rebuild_s", f"{name}_cast_s"))
    if any(median.get(key) is None for key in keys):
        return None
    return 1e3 * sum(median[key] for key in keys)


def _sweep(result):
    """Whether ``result`` belongs to the Suzanne subdivision sweep (drawn as a line)."""
    return result.get("scene", "").startswith("suzanne-")


def _series(ax, results, figure_of, color, marker, label):
    """One path's figures against triangles: a line over the sweep, hollow markers for
    the other meshes; nothing where the figure is None."""
    points = [(r["triangles"], figure_of(r), _sweep(r)) for r in results
              if figure_of(r) is not None]
    sweep = [(t, v) for t, v, in_sweep in points if in_sweep]
    others = [(t, v) for t, v, in_sweep in points if not in_sweep]
    if sweep:
        ax.plot(*zip(*sweep), marker=marker, color=color, label=label)
    if others:
        ax.plot(*zip(*others), linestyle="none", marker=marker, color=color,
                markerfacecolor="none", label=None if sweep else label)


def _axes(ax, results, label):
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("triangles (lines: Suzanne subdivided; hollow: other meshes)")
    ax.set_ylabel(label)
    for result in results:
        if not _sweep(result):
            ax.axvline(result["triangles"], linestyle=":", color="0.6", linewidth=0.8)
            ax.text(result["triangles"], 1.0, f" {result['object']}", rotation=90, fontsize=7,
                    va="top", ha="right", transform=ax.get_xaxis_transform())
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7)


def write_performance(performance, results, command, machine):
    """Rewrites the side-by-side section of the markdown file ``performance`` with
    ``results``, their plots in ``side-by-side/`` beside it; returns the plot paths."""
    performance = pathlib.Path(performance)
    paths = write_plots(results, performance.parent / "side-by-side")
    relative = {name: path.relative_to(performance.parent).as_posix()
                for name, path in paths.items()}
    from .bench import PERFORMANCE_PREAMBLE

    write_section(performance, SECTION, TITLE,
                  side_by_side_markdown(results, command, machine_text(machine), relative),
                  PERFORMANCE_PREAMBLE)
    return paths
