"""The numpy/torch neural renderer and hit reconstruction: the test oracle of the render
kernels (``vdnif_addon/render.py``, ``kernels/render.py``), as the product ran them before.

The numpy walk (``oracles.walk.Walk``) advances every ray one cell per wave; the network
evaluates each wave's segments; a ray's hit is placed on its first candidate segment and
made a hit, ending its walk, by its first segment predicted hit (DESIGN section 9).
"""

import numpy as np
import torch

from oracles.geometry import deformed_normals, trilinear_jacobian
from oracles.walk import Walk
from vdnif_addon.inference.neural_render import predict_segments
from vdnif_addon.passes import Passes


def neural_passes(network, grid, albedo_table, cells, entry_caster, origins, directions,
                  device="cpu"):
    """(Passes, stats) as the old renderer: ``cells`` an ``oracles.walk.DeformedCells``."""
    rays = len(origins)
    passes, placed = Passes.empty(rays), Passes.empty(rays)
    walk = Walk(cells, entry_caster, origins, directions)
    stats = dict(segments=0, waves=0)
    table = torch.as_tensor(np.asarray(albedo_table, np.float32), device=device)
    while walk.running():
        walk.advance()
        wave = walk.take_new()
        if not len(wave):
            continue
        prediction = predict_segments(network, grid, wave, device)
        hit = prediction["hit"].cpu().numpy()
        candidate = prediction["candidate"].cpu().numpy() & ~placed.hit[wave.ray]
        index = np.flatnonzero(candidate)
        material = prediction["material"][candidate]
        albedo = (prediction["albedo"][candidate] if "albedo" in prediction
                  else table[material])
        set_hits(placed, wave.ray[index], cells, wave, index,
                 prediction["fraction"][candidate].cpu().double().numpy(),
                 prediction["normal"][candidate].cpu().double().numpy(),
                 albedo.cpu().numpy(), material.cpu().numpy())
        done = wave.ray[np.flatnonzero(hit)]
        for name in ("hit", "distance", "normal", "albedo", "material"):
            getattr(passes, name)[done] = getattr(placed, name)[done]
        walk.stop(done)
        stats["segments"] += len(wave)
        stats["waves"] += 1
    stats["truncated"] = walk.active()
    return passes, stats


def set_hits(passes, ray, cells, segments, k, fraction, rest_normal, albedo, material):
    """Hits from their segment ``k`` and hit ``fraction``: distance ``t0 + fraction * l``,
    the rest normal carried to deformed space by ``J^-T`` at the rest hit point."""
    passes.hit[ray] = True
    passes.distance[ray] = segments.t0[k] + fraction * segments.length[k]
    point = segments.p0[k] + fraction[:, None] * (segments.p1[k] - segments.p0[k])
    cell = segments.cell[k]
    low, high = cells.rest_corners[cell, 0], cells.rest_corners[cell, 7]
    local = np.clip((point - low) / (high - low), 0.0, 1.0)
    jacobian = trilinear_jacobian(cells.corners[cell], local)
    passes.normal[ray] = deformed_normals(rest_normal, jacobian)
    passes.albedo[ray] = albedo
    passes.material[ray] = material
