"""What a ``side-by-side`` run reports, from ``compare_paths`` results alone (JSON-ready
dicts): no bpy, no timing. The markdown tables (a column per scene, image size and thread
setting) with the secondary rays' where they were timed, the targets, the section of
``docs/performance.md``, and the plots: rays/s and pose totals against triangle count, model
bytes against mesh + BVH bytes, and the crossover figure (pose totals per image size and
thread setting, where the neural pose costs as much as each classical one, bytes beside
them)."""

import pathlib

from ..inference.metrics import SPEED_MIN_HIT_IOU
from ..safe_io import atomic_path
from ..text import percent
from ..threads import RENDER_TORCH_THREADS
from .baselines import BASELINES, BLENDER_THREADS
from .report import write_section

SECTION = "side-by-side"
TITLE = "Side by side with the classical baselines"
PATHS = {"neural": "neural render (walk + network)",
         "bvhtree": "BVHTree (Python loop): `BVHTree.FromObject`, `ray_cast` loop",
         "warp": "Warp mesh BVH: refit, `mesh_query_ray` kernel",
         "embree_refit": "Embree (C API): refit (`RTC_BUILD_QUALITY_REFIT`), packet casts",
         "embree_rebuild": "Embree (C API): new build per pose, packet casts"}
BUILD = {"bvhtree": "rebuild", "warp": "refit", "embree_refit": "refit",
         "embree_rebuild": "rebuild"}

# The targets of the neural path, set for 2 CPU cores.
TARGET_RAYS_PER_S = 0.8e6          # neural render, trained model, unseen poses, 256x256
TARGET_NETWORK_SHARE = 0.8         # network's segments/s in the render / over one batch
TARGET_WALK = 1.5                  # deformed walk / static DDA walk, rest pose
TARGET_WALK_NETWORK = 1.05         # the same with the network over every walked segment
TARGET_PREPARE_S = 0.010           # per-pose preparation, set for the bunny at R 32
TARGET_PREPARE_RATIO = 0.05        # per-pose preparation / BVHTree rebuild, set for 1 M tris

PLOTS = {"speed": "side-by-side-speed.png", "bytes": "side-by-side-bytes.png"}
SHORT = {"neural": "neural", "bvhtree": "BVHTree (Python loop)", "warp": "Warp refit",
         "embree_refit": "Embree refit", "embree_rebuild": "Embree rebuild"}
STYLES = {"neural": ("C3", "o"), "bvhtree": ("C0", "s"), "warp": ("C2", "^"),
          "embree_refit": ("C1", "D"), "embree_rebuild": ("C4", "v")}
# A thread setting's line: the largest solid, the others dashed, then dotted.
LINES = ("-", "--", ":", "-.")


SECONDARY_BASELINES = ("warp", "embree_refit", "embree_rebuild")
SECONDARY_PATHS = ("neural", *SECONDARY_BASELINES)


def _targets():
    """(label, figure(result) -> value or None, format, goal(value) -> bool)."""
    return (
        (f"neural render >= {TARGET_RAYS_PER_S / 1e6:g} M rays/s",
         lambda r: r["rays_per_s"]["neural"], lambda v: f"{v / 1e6:.3g} M",
         lambda v: v >= TARGET_RAYS_PER_S),
        (f"network inside the render >= {TARGET_NETWORK_SHARE * 100:.0f} % of its segments/s over "
         "one batch (the rest view's every walked segment)", network_share,
         lambda v: f"{v * 100:.0f} %", lambda v: v >= TARGET_NETWORK_SHARE),
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


def network_share(result):
    """The network's segments per second inside the neural render (its waves) over its
    segments per second in one batch of every segment the rest view walks, or None where
    the render was not timed: what the waves' sizes cost the network."""
    median = result["median"]
    keys = ("neural_segments", "neural_network_s", "walk_segments", "all_segments_network_s")
    if any(not median.get(key) for key in keys):
        return None
    return ((median["neural_segments"] / median["neural_network_s"])
            / (median["walk_segments"] / median["all_segments_network_s"]))


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
    targets, speeds, pose totals (and secondary rays where timed), ratios, steps, agreement
    of the baselines, models, bytes, settings.
    ``command`` is the command that measured them, ``machine`` a ``machine_text`` line, and
    ``plots`` {"speed" | "bytes": relative path} the plot files to show."""
    heads = " | ".join(column_head(r) for r in results)
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
    lines += glance_table(results)
    lines += table("Targets (met / missed; n/a where the figure is withheld or not run).",
                   [(label, [f"{text}{_met(met)}" for text, met in cells])
                    for label, *cells in _transpose_targets(results)])
    speed_rows = [(f"{PATHS[name]}, rays/s", ["n/a" if r["rays_per_s"][name] is None
                                              else f"{r['rays_per_s'][name]:,.0f}"
                                              for r in results])
                  for name in ("neural", *BASELINES)]
    speed_rows += [(f"{SHORT[name]}: threads", [threads_text(r, name) for r in results])
                   for name in ("neural", *BASELINES)]
    total_rows = [("neural pose total: preparation + render", [
        "n/a" if pose_total(r, "neural") is None else f"{pose_total(r, 'neural'):.1f}"
        for r in results])]
    total_rows += [(f"{SHORT[b]} pose total: evaluation, "
                    f"{'' if b == 'bvhtree' else 'read, '}{BUILD[b]}, casts",
                    [f"{pose_total(r, b):.1f}" for r in results]) for b in BASELINES]
    lines += table("Speed: rays per second of the casts or the neural render, median over "
                   "repeats, and the threads each step ran on.", speed_rows)
    lines += table("Pose total, milliseconds per pose (Blender's evaluation included on "
                   "every side).", total_rows)
    lines += secondary_markdown(results, table, threads_text)
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
                       ("model (variant, MLP arithmetic)", [
                           f"`{n['model']}` ({n['variant']}, {n.get('precision', 'float32')})"
                           if (n := r["network"])["model"] else "none" for r in results]),
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


def glance_table(results):
    """Markdown lines of the table a reader wants first: one row per mesh, image size and
    thread setting, each path's pose total (milliseconds, Blender's evaluation included),
    the neural pose over the cheapest classical one (the median of each repeat's ratio, as
    in the targets), and the model's holes and extras."""
    heads = ["mesh (triangles)", "image", "threads", "neural",
             *(SHORT[b] for b in BASELINES), "neural / cheapest classical",
             "holes / extras (vs true)"]
    lines = ["At a glance: milliseconds per pose, median over repeats (the tables below "
             "hold every step and figure).", "", "| " + " | ".join(heads) + " |",
             "|---" * len(heads) + "|"]
    for r in results:
        totals = {name: pose_total(r, name) for name in ("neural", *BASELINES)}
        classical = [(totals[b], b) for b in BASELINES if totals[b] is not None]
        ratio = "n/a"
        if totals["neural"] is not None and classical:
            cheapest = min(classical)[1]
            ratio = f"{r['ratios'][f'pose_neural_over_{cheapest}']:.3g} ({SHORT[cheapest]})"
        rates = _rates_text(r["network"])
        cells = [f"{r['object']} ({r['triangles']:,})", f"{r['width']}x{r['height']}",
                 str(r["threads"]["setting"]),
                 *("n/a" if totals[name] is None else f"{totals[name]:.1f}"
                   for name in ("neural", *BASELINES)), ratio, rates]
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def _step_rows():
    """(label, record key) of every step the steps table shows."""
    casts = {"bvhtree": "`ray_cast` loop", "warp": "`mesh_query_ray` kernel",
             "embree_refit": "packets", "embree_rebuild": "packets"}
    builds = {"bvhtree": "`BVHTree.FromObject`", "warp": "copy in + `refit`",
              "embree_refit": "commit (refit)", "embree_rebuild": "commit (new build)"}
    rows = []
    for b in BASELINES:
        rows += [(f"{SHORT[b]}: evaluate the mesh's modifiers", f"{b}_evaluate_s")]
        rows += [] if b == "bvhtree" else [(f"{SHORT[b]}: read the evaluated vertices",
                                            f"{b}_read_s")]
        rows += [(f"{SHORT[b]}: {builds[b]}", f"{b}_build_s"),
                 (f"{SHORT[b]}: casts ({casts[b]})", f"{b}_cast_s")]
    return (*rows,
            ("neural: evaluate the corner helper's modifiers", "neural_evaluate_s"),
            ("neural: read corners + refit cells and entry BVH (`prepare_s`)",
             "neural_prepare_s"),
            ("neural: render (walk + network)", "neural_render_s"),
            ("neural render: walk (seconds in it, the lanes' mean)", "neural_walk_s"),
            ("neural render: network (seconds in it, the lanes' mean)", "neural_network_s"),
            ("rest view: deformed walk (`tracing.traverse.traverse`)", "deformed_walk_s"),
            ("rest view: static DDA walk (`tracing.static_grid.StaticGrid`)", "static_walk_s"),
            ("rest view: network over every walked segment", "all_segments_network_s"))


STEP_ROWS = _step_rows()


def column_head(result):
    """A table column's head: the mesh, the image size and the thread setting."""
    return (f"{result['object']} ({result['triangles']:,} triangles), "
            f"{result['width']}x{result['height']}, {result['threads']['setting']} "
            "thread setting")


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
    embree = result["embree"]
    native = ("native on this CPU" if embree["native"]
              else "not native on this CPU: Embree loops over their rays")
    return (
        f"Per repeat, each of {result['poses']} unseen poses (evaluation poses, disjoint from "
        "the model's training poses) is seen from an orbit camera of "
        f"{result['width']}x{result['height']} rays in the object's local space. Every "
        "classical baseline starts from Blender's evaluation of the pose (the object is "
        "tagged, then `evaluated_depsgraph_get()`): **BVHTree (Python loop)** rebuilds with "
        "`BVHTree.FromObject` and casts in a Python loop of `ray_cast` (no batch API); "
        "**Warp** reads the evaluated vertices (`foreach_get`), copies them into its mesh BVH "
        "built once on the rest triangles, refits it and casts with one `mesh_query_ray` "
        "kernel; **Embree** (its C API through ctypes, on the library `embreex` ships) reads "
        "the vertices into the vertex array it shares with Embree, then commits: **Embree "
        "refit** is a dynamic scene of build quality LOW whose mesh has build quality "
        "`RTC_BUILD_QUALITY_REFIT` (Embree refits it, as Cycles does for a deforming mesh in "
        "the viewport), **Embree rebuild** a static scene that builds a new BVH on each "
        "commit; both are robust (watertight) and cast "
        f"`rtcIntersect{embree['width']}` packets ({native}) split over the setting's "
        "threads. The **neural** path re-evaluates the corner "
        "helper's modifiers, reads the deformed corners and refits the cells and the entry "
        "BVH (its preparation), then renders (`inference.neural_render.neural_passes`: walk "
        "+ network in waves, a ray stops at its first predicted hit). A thread setting of N: "
        "Embree builds and casts on N threads, Warp's casts are split over N launches at "
        "once (a Warp CPU launch runs on one thread), torch runs the MLP on N - 1 (at least "
        "one), the neural render renders up to N lanes of rays at once, each on a thread of "
        "its own (walk, Warp encoder and MLP; one lane splits its encoder over N and encodes "
        "its next batch beside its MLP where N > 1); the `ray_cast` loop, "
        "Warp's refit and its other CPU launches run on one thread at any setting; Blender's "
        "evaluation and `BVHTree.FromObject` run on Blender's own threads. On the rest pose, "
        "the deformed walk (`tracing.traverse.traverse`) is timed against the static DDA walk "
        "(`tracing.static_grid.StaticGrid`) of the same rays, and the network over every "
        "walked segment is added to both. Each ratio is computed within one repeat from the "
        "per-pose means of both sides, timed alternately in one process after one untimed "
        "pass.")


def _withheld_lines(results):
    withheld = dict.fromkeys((r["object"], r["speed_withheld"]) for r in results
                             if r["speed_withheld"] is not None)
    return [] if not withheld else [
        f"Neural speeds n/a (only a trained model whose hit IoU against the true reference "
        f"reaches {SPEED_MIN_HIT_IOU} on these views has speeds):", "",
        *(f"- {name}: {reason}." for name, reason in withheld), ""]


def _transpose_targets(results):
    per_result = [target_rows(r) for r in results]
    return [(label, *[(rows[i][1], rows[i][2]) for rows in per_result])
            for i, (label, _, _) in enumerate(per_result[0])]


def _met(met):
    return "" if met is None else (" (met)" if met else " (**missed**)")


def threads_text(result, name):
    """On how many threads each step of path ``name`` ran in ``result``."""
    threads = result["threads"]
    if name == "neural":
        lanes, share = threads["walk_lanes"], threads["setting"] // threads["walk_lanes"]
        split, mlp = ((threads.get("encoder", 1), threads["torch"]) if lanes == 1 else
                      (1, min(threads["torch"], RENDER_TORCH_THREADS, share)))
        return (f"{lanes} lane(s) at once, each on a thread of its own: its walk, its Warp "
                f"encoder split over {split}, its MLP on {mlp} torch thread(s)")
    counts = threads[name]

    def count(value):
        return ("Blender's threads" if value == BLENDER_THREADS
                else f"{value} thread(s)" if isinstance(value, int) else str(value))

    return f"{BUILD[name]} on {count(counts['build'])}, casts on {count(counts['casts'])}"


def _agreement_text(agreement):
    difference = agreement["max_distance_difference"]
    return (f"{agreement['differing_hits']} of {agreement['rays']:,} rays differ; "
            + ("no common hit" if difference is None else f"max {difference:.2g}"))


def _iou_text(network):
    if network["hit_iou"] is None:
        return "n/a"
    return f"{network['hit_iou']:.4f}, {_rates_text(network)}"


def _rates_text(network):
    """The model's false-negative / false-positive rates against the true reference."""
    if network.get("false_negative_rate") is None:
        return "n/a"
    return f"{percent(network['false_negative_rate'])} / {percent(network['false_positive_rate'])}"


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
    vector = f" ({machine['vector']})" if machine.get("vector") else ""
    return (f"Machine: {machine['cpu']}{vector}, {machine['cores']} cores available; load average "
            f"{machine['load_before']:.2f} before and {machine['load_after']:.2f} after the "
            f"run (other work on the machine slows every side alike only roughly: compare "
            f"ratios, not absolute times). OMP_NUM_THREADS={machine['omp_num_threads']}, torch "
            f"{machine['torch']} on {machine['torch_threads']} thread(s); Warp "
            f"{machine['warp']} on {machine['warp_device']} (a CPU launch runs on one "
            f"thread); Embree through embreex {machine['embreex']}; Blender "
            f"{machine['blender']}.")


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


def secondary_markdown(results, table, threads_text):
    """Markdown lines of the secondary table of ``results`` (those timed with
    ``--secondary``), one column per result, ``table`` as ``side_by_side_markdown``'s."""
    timed = [r for r in results if r.get("secondary")]
    if not timed:
        return []
    first = timed[0]["secondary"]
    counts = first["settings"]["samples"]
    rows = []
    for samples in counts:
        for name in SECONDARY_PATHS:
            rows.append((f"{SHORT[name]}, {samples} AO sample(s): secondary rays/s (rays "
                         "per pose, ms)", [_rate_text(r, name, samples) for r in timed]))
        for name in SECONDARY_PATHS:
            rows.append((f"{SHORT[name]}, {samples} AO sample(s): pose total ms "
                         "(preparation + primary + secondary)",
                         [_value(r, name, samples, "pose_total_ms", "{:.1f}")
                          for r in timed]))
        for name in SECONDARY_PATHS:
            rows.append((f"{SHORT[name]}, {samples} AO sample(s): mean AO, lit share "
                         "over its hits", [_value(r, name, samples, "ao_mean", "{:.3f}")
                                           + ", " + _value(r, name, samples, "lit_share",
                                                           "{:.3f}") for r in timed]))
    rows += [(f"where the cheaper side changes: neural / {SHORT[b]}",
              [r["secondary"]["trade"][b]["text"] for r in timed])
             for b in SECONDARY_BASELINES]
    rows += [(f"{SHORT[name]}: threads", [threads_text(r, name) for r in timed])
             for name in SECONDARY_PATHS]
    settings = first["settings"]
    title = (f"Secondary rays per pose, from each path's own primary hits: "
             f"{' and '.join(map(str, counts))} cosine-weighted AO rays per hit up to "
             f"{settings['ao_distance']:g} object units, and a shadow ray towards the light "
             f"({settings['light']}) from each hit facing it; rays/s and milliseconds are "
             "medians over repeats of the per-pose means, the pose total adds the path's "
             "preparation and primary pass (Blender's evaluation included).")
    notes = [f"- {SHORT[name]}: not timed with secondary rays: {reason}."
             for name, reason in first["skipped"].items()]
    return table(title, rows) + notes + [""]


def _value(result, name, samples, what, form):
    value = result["secondary"]["paths"][name][str(samples)][what]
    return "n/a" if value is None else form.format(value)


def _rate_text(result, name, samples):
    figures = result["secondary"]["paths"][name][str(samples)]
    if figures["rays_per_s"] is None:
        return "n/a"
    return (f"{figures['rays_per_s']:,.0f} ({figures['rays']:,.0f}, "
            f"{figures['ms']:.1f})")


def secondary_line(result):
    """One printed line of a result's secondary rays: rays/s and pose totals per path."""
    parts = []
    for samples in result["secondary"]["settings"]["samples"]:
        cells = []
        for name in SECONDARY_PATHS:
            figures = result["secondary"]["paths"][name][str(samples)]
            cells.append(f"{name} " + ("n/a" if figures["rays_per_s"] is None else
                                       f"{figures['rays_per_s']:,.0f} rays/s, "
                                       f"{figures['pose_total_ms']:.1f} ms/pose"))
        parts.append(f"{samples} AO sample(s): " + "; ".join(cells))
    return "  secondary rays, " + " | ".join(parts)


# The plots.


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
