"""The network's secondary rays walked on past the surface they leave by renders of their own,
one per skip: the host loop that ``neural_render.WalkPast`` replaced (the render now starts
such rays again within its waves), kept as the test oracle."""

import numpy as np

from vdnif_addon.inference.neural_render import neural_passes
from vdnif_addon.settings import (
    SECONDARY_SELF_COSINE,
    SECONDARY_SELF_REACH,
    SECONDARY_SELF_SKIPS,
)


def neural_occluded(network, grid, albedo_table, cells, offset, device="cpu"):
    """``secondary.neural_occluded`` as a loop of renders: each skip renders the rays whose
    first hit was the surface they left, from an offset past that hit."""
    def occluded(origins, directions, max_distance, leaving, start_cells=None):
        reach = np.broadcast_to(np.asarray(max_distance, np.float64), (len(origins),))
        walked, blocked = np.zeros(len(origins)), np.zeros(len(origins), bool)
        rows = np.arange(len(origins))
        starts = start_cells
        for skip in range(SECONDARY_SELF_SKIPS + 1):
            left = reach[rows] - walked[rows]
            passes, _ = neural_passes(network, grid, albedo_table, cells,
                                      origins[rows] + walked[rows, None] * directions[rows],
                                      directions[rows], device, max_distance=left,
                                      start_cells=starts)
            blocked[rows] = passes.hit & (passes.distance <= left)
            own = blocked[rows] & (walked[rows] + passes.distance
                                   <= SECONDARY_SELF_REACH * offset)
            own &= (passes.normal * leaving[rows]).sum(1) > SECONDARY_SELF_COSINE
            if skip == SECONDARY_SELF_SKIPS or not own.any():
                break
            walked[rows[own]] += passes.distance[own] + offset
            rows = rows[own]
            starts = passes.cell[own]
        return blocked
    return occluded
