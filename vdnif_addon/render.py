"""Neural rendering of the passes (DESIGN section 9): walk the deformed cells wave by wave and
ask the network only about the segments of rays it has not resolved yet."""

import time

import numpy as np
import torch

from .metrics import Passes
from .references import set_hits
from .traverse import Walk


def neural_passes(network, grid, albedo_table, cells, entry_caster, origins, directions,
                  device="cpu"):
    """(Passes, stats) predicted by ``network`` for rays in the object's deformed space.

    Each wavefront step adds at most one segment per unresolved ray; the network evaluates
    them in one batch, the first segment with occlusion probability > 0.5 resolves its ray
    (distance ``t0 + fraction * l``, normal by ``J^-T``), and resolved rays stop walking.
    Without an albedo head the albedo comes from ``albedo_table`` (M, 3) by material.
    """
    rays = len(origins)
    passes = Passes.empty(rays)
    walk = Walk(cells, entry_caster, origins, directions)
    stats = dict(segments=0, waves=0, walk_s=0.0, network_s=0.0)
    table = torch.as_tensor(np.asarray(albedo_table, np.float32), device=device)
    while walk.running():
        clock = time.perf_counter()
        walk.advance()
        wave = walk.take_new()
        stats["walk_s"] += time.perf_counter() - clock
        if not len(wave):
            continue
        clock = time.perf_counter()
        prediction = predict_segments(network, grid, wave, device)
        hit = prediction["hit"].cpu().numpy()
        index = np.flatnonzero(hit)
        material = prediction["material"][hit]
        albedo = prediction["albedo"][hit] if "albedo" in prediction else table[material]
        set_hits(passes, wave.ray[index], cells, wave, index,
                 prediction["fraction"][hit].cpu().double().numpy(),
                 prediction["normal"][hit].cpu().double().numpy(),
                 albedo.cpu().numpy(), material.cpu().numpy())
        walk.stop(wave.ray[index])
        stats["network_s"] += time.perf_counter() - clock
        stats["segments"] += len(wave)
        stats["waves"] += 1
    stats["truncated"] = walk.active()
    return passes, stats


def predict_segments(network, grid, segments, device):
    """``network.predict`` of Segments (rest-space end points normalized to the grid)."""
    rest_length = np.linalg.norm(segments.p1 - segments.p0, axis=1)
    return network.predict(_tensor(grid.normalize(segments.p0), device),
                           _tensor(grid.normalize(segments.p1), device),
                           _tensor(rest_length, device), grid.voxel_size)


def _tensor(array, device):
    return torch.as_tensor(np.asarray(array, np.float32), device=device)
