"""Secondary rays in the side-by-side study (``side-by-side --secondary``): whether a neural
pose stays cheaper than a classical one once each primary hit casts ambient-occlusion and
shadow rays.

Per pose, after the primary pass of each path, every path casts the secondary rays of its own
primary hits (``inference.secondary.secondary_passes``: ``samples`` cosine-weighted AO rays
per hit up to the AO distance, and a shadow ray towards the light from each hit that faces
it; a hit facing away is in its own shadow without a cast), once at 1 AO sample per pixel
and once at the run's N, so that one run shows how the trade moves with rays per pose. The
neural path answers them through the deformed walk and the network from the network's hits
and normals; Warp's refit BVH and Embree (refit and rebuilt) through the BVH their pose
prepared, from their own first hits and the hit triangle's geometric normal (computed from
the pose's vertices inside the timed step). Every path asks the same question, the first hit
within reach. Blender's BVHTree is left out: its Python loop of ``ray_cast`` casts some
10^5 rays per second, so the AO rays of one pose take longer than every other path's
whole run.

A path's secondary time counts everything after its primary pass: normals, start points,
directions and the casts. Its pose total at S samples is its preparation, its primary pass
and that time. The records, medians and tables are built here; ``side_by_side`` runs it.
"""

import dataclasses
import statistics
import time

from ..inference.secondary import (
    counted,
    exact_occluded,
    mesh_primary,
    neural_occluded,
    secondary_passes,
)
from .side_by_side_plots import SHORT, pose_total

SECONDARY_BASELINES = ("warp", "embree_refit", "embree_rebuild")
SECONDARY_PATHS = ("neural", *SECONDARY_BASELINES)
NEURAL_PREFIX = "neural_secondary"
SKIPPED = {"bvhtree": "its Python loop of `ray_cast` (about 10^5 rays/s) would take longer "
                      "than every other path together"}


def sample_counts(settings):
    """The AO samples per pixel a run times: 1 and the settings' N (once where N is 1)."""
    return sorted({1, settings.samples})


def key(name, samples, what):
    """The record key of path ``name``'s secondary ``what`` ("s", "ao_rays", "shadow_rays",
    "ao_mean", "lit_share") at ``samples`` AO samples per pixel."""
    return f"{name}_secondary{samples}_{what}"


def secondary_record(baselines, casts, model, predicted, cells, grid, triangles, rays,
                     object_size, settings, sync):
    """Record entries of one pose: per path of ``SECONDARY_PATHS`` that ran and per AO
    sample count, the seconds of its secondary rays, the AO and shadow rays it cast, its
    mean AO and its lit share over its hits. ``casts`` {baseline: (index, t)} are the
    classical primary casts of ``rays`` (origins, directions), ``predicted`` the network's
    primary passes (None without ``model``) over ``grid``; ``sync`` waits for queued device
    work."""
    paths = {}
    for baseline in baselines:
        if baseline.name in SECONDARY_BASELINES:
            paths[baseline.name] = (lambda b=baseline: (
                mesh_primary(b.vertices, triangles, *casts[b.name]), exact_occluded(b)), None)
    if model is not None:
        # The network's hits start their rays off by its own error, as its passes do.
        offset = model.secondary_offset(object_size)
        network = neural_occluded(model.network, grid, model.albedo_table, cells, offset,
                                  model.device)
        paths["neural"] = (lambda: (predicted, network), offset)
    record = {}
    for samples in sample_counts(settings):
        at = dataclasses.replace(settings, samples=samples)
        for name, (prepare, offset) in paths.items():
            calls = []
            sync()
            start = time.perf_counter()
            # A name of its own: the neural path's lambda reads ``network`` when called, so
            # rebinding that name here would hand it a baseline's occluder.
            primary, answers = prepare()
            passes = secondary_passes(primary, *rays, counted(answers, calls),
                                      object_size, at, offset)
            sync()
            seconds = time.perf_counter() - start
            # secondary_passes asks for the AO rays first, then the shadow rays
            ao_rays, shadow_rays = calls
            hits = int(passes.hit.sum())
            record.update({
                key(name, samples, "s"): seconds, key(name, samples, "ao_rays"): ao_rays,
                key(name, samples, "shadow_rays"): shadow_rays,
                key(name, samples, "ao_mean"): float(passes.ao[passes.hit].mean())
                if hits else None,
                key(name, samples, "lit_share"): float(passes.lit[passes.hit].mean())
                if hits else None})
    return record


def withhold(record):
    """Drops the neural path's secondary entries from a pose ``record`` (its speeds are
    withheld)."""
    for name in [k for k in record if k.startswith(NEURAL_PREFIX)]:
        del record[name]


def secondary_summary(result, settings, network_offset=None):
    """The secondary table of a ``compare_paths`` ``result`` timed with ``settings`` (the
    network's hits started ``network_offset`` object units off, when it ran): per
    path and AO sample count, the rays per pose, their milliseconds and rays per second,
    the pose total, the mean AO and lit share (medians over repeats; None where not run
    or withheld), and per classical path where the cheaper side changes."""
    counts = sample_counts(settings)
    paths = {}
    for name in SECONDARY_PATHS:
        paths[name] = {str(samples): _figures(result, name, samples) for samples in counts}
    return {"settings": dict(settings.describe(network_offset), samples=counts),
            "paths": paths, "skipped": SKIPPED,
            "trade": {b: trade_point(paths["neural"], paths[b], counts)
                      for b in SECONDARY_BASELINES}}


def _figures(result, name, samples):
    runs = [[r for r in run["poses"] if key(name, samples, "s") in r]
            for run in result["runs"]]
    if not all(runs):
        return {"rays": None, "ao_rays": None, "shadow_rays": None, "ms": None,
                "rays_per_s": None, "pose_total_ms": None, "ao_mean": None, "lit_share": None}

    def median(what):
        values = [statistics.fmean(r[key(name, samples, what)] for r in poses)
                  for poses in runs if all(r[key(name, samples, what)] is not None
                                           for r in poses)]
        return statistics.median(values) if values else None

    rays = [[r[key(name, samples, "ao_rays")] + r[key(name, samples, "shadow_rays")]
             for r in poses] for poses in runs]
    rates = [statistics.fmean(count) / statistics.fmean(r[key(name, samples, "s")]
                                                        for r in poses)
             for count, poses in zip(rays, runs)]
    ms = 1e3 * median("s")
    primary = pose_total(result, name)
    return {"rays": statistics.median(statistics.fmean(count) for count in rays),
            "ao_rays": median("ao_rays"), "shadow_rays": median("shadow_rays"), "ms": ms,
            "rays_per_s": statistics.median(rates),
            "pose_total_ms": None if primary is None else primary + ms,
            "ao_mean": median("ao_mean"), "lit_share": median("lit_share")}


def trade_point(neural, classical, counts):
    """Where the neural pose total meets a classical one, both taken as linear in the AO
    samples through the two measured counts: "samples" where they meet between them (None
    otherwise), "beyond" where the lines meet past N (an extrapolation, None otherwise)."""
    totals = [(neural[str(s)]["pose_total_ms"], classical[str(s)]["pose_total_ms"])
              for s in counts]
    if any(n is None for n, _ in totals):
        return {"samples": None, "beyond": None, "text": "n/a (no neural speed)"}
    ratios = ", ".join(f"{n / c:.3g} at {s}" for (n, c), s in zip(totals, counts))
    differences = [n - c for n, c in totals]
    meet = None
    if len(counts) == 2 and differences[0] != differences[1]:
        low, high = counts
        meet = low + (high - low) * differences[0] / (differences[0] - differences[1])
    if meet is not None and counts[0] < meet < counts[-1]:
        way = "from" if differences[0] > 0 else "up to"
        return {"samples": meet, "beyond": None,
                "text": f"neural cheaper {way} {meet:.3g} AO samples (neural / "
                        f"classical {ratios})"}
    side = "neural" if differences[-1] < 0 else "classical"
    beyond = meet if meet is not None and meet >= counts[-1] else None
    text = (f"{side} cheaper at {' and '.join(map(str, counts))} AO samples (neural / "
            f"classical {ratios})")
    if beyond is not None:
        text += f"; the lines meet at {beyond:.3g} AO samples (extrapolated)"
    return {"samples": None, "beyond": beyond, "text": text}


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
