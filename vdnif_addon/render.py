"""Neural rendering of the passes (DESIGN section 9): the deformed walk and the network in
waves, so that a ray is walked and evaluated only up to its first predicted hit.

Every ray keeps its walker state on the device (``kernels.walk.RayWalk``). A wave walks each
unresolved ray on by at most k segments (one kernel launch), the network evaluates the wave's
segments in one batch, and a kernel turns each ray's first predicted hit into its passes
(``kernels/render.py``) and ends its walk; finished rays leave the list on the device. Only
two counts per wave come back to the host, to size the next launch and the network batch.
"""

import contextlib
import sys
import time

import numpy as np
import torch
import warp as wp

from .errors import VDNIFError
from .kernels import render as kernel
from .kernels import runtime
from .kernels.walk import RayWalk, segment_buffer
from .metrics import Passes

# Segments per ray and wave: k for wave w (w = 0, 1, ...). A wave costs a fixed overhead
# (launches, one network call) and every segment past a ray's hit in its wave is evaluated
# for nothing. Most rays that hit, hit within their first cells, while rays that survive a
# few waves mostly pass through the object and need all their cells: k grows.
WAVE_SEGMENTS = (1, 1, 2, 4, 8, 16)


def wave_segments(wave, schedule=WAVE_SEGMENTS):
    """k of wave ``wave``: the schedule's entry, its last one beyond it."""
    return schedule[min(wave, len(schedule) - 1)]


def neural_passes(network, grid, albedo_table, cells, origins, directions, device="cpu",
                  schedule=WAVE_SEGMENTS):
    """(Passes, stats) predicted by ``network`` for rays (N, 3) in the object's deformed
    space, walked through ``cells`` (a ``kernels.cells.DeviceCells`` in the pose).

    The first segment with occlusion probability > 0.5 resolves its ray: distance
    ``t0 + fraction * l``, normal by ``J^-T``, albedo from the albedo head or, without
    one, from ``albedo_table`` (M, 3) by material. ``device`` is the network's torch
    device; the cells' Warp device must be the same.
    """
    warp_device = cells.device
    if runtime.device(device) != runtime.device(warp_device):
        raise VDNIFError(f"the network runs on {device} but the cells are on {warp_device}: "
                         "render with both on one device")
    runtime.load(sys.modules[kernel.__name__], warp_device)
    rays = len(origins)
    stats = dict(segments=0, waves=0, walk_s=0.0, network_s=0.0)
    with _torch_stream(device):
        walk = RayWalk(cells, origins, directions)
        passes = kernel.empty_passes(rays, warp_device)
        first = wp.full(rays, int(kernel.NO_HIT), dtype=wp.int32, device=warp_device)
        table = wp.array(np.asarray(albedo_table, np.float32).reshape(-1, 3), dtype=wp.vec3,
                         device=warp_device)
        buffer = inputs = None
        while walk.count:
            per_wave = wave_segments(stats["waves"], schedule)
            if buffer is None or walk.count * per_wave > buffer.capacity:
                buffer = segment_buffer(walk.count * per_wave, warp_device)
                inputs = [wp.empty(buffer.capacity, dtype=dtype, device=warp_device)
                          for dtype in (wp.vec3, wp.vec3, wp.float32)]
            clock = time.perf_counter()
            buffer.cursor.zero_()
            count = walk.advance(buffer, per_wave)
            stats["walk_s"] += time.perf_counter() - clock
            clock = time.perf_counter()
            if count:
                _evaluate(network, grid, walk, buffer, count, inputs, table, first, passes)
                stats["segments"] += count
            stats["network_s"] += time.perf_counter() - clock
            clock = time.perf_counter()
            walk.drop_finished()
            stats["walk_s"] += time.perf_counter() - clock
            stats["waves"] += 1
        counter = wp.zeros(1, dtype=wp.int32, device=warp_device)
        if rays:
            wp.launch(kernel.unresolved_truncated, dim=rays,
                      inputs=[walk.state, passes, counter], device=warp_device)
        stats["truncated"] = int(counter.numpy()[0])
    return Passes(hit=passes.hit.numpy().astype(bool), distance=passes.distance.numpy(),
                  normal=passes.normal.numpy(), albedo=passes.albedo.numpy(),
                  material=passes.material.numpy()), stats


def _evaluate(network, grid, walk, buffer, count, inputs, table, first, passes):
    """The network over a wave's ``count`` segments, then each ray's first hit made into
    passes (its walk ends there)."""
    device = walk.device
    p0, p1, rest_length = inputs
    wp.launch(kernel.network_inputs, dim=count,
              inputs=[buffer, wp.vec3d(*grid.origin), wp.float64(grid.extent), p0, p1,
                      rest_length], device=device)
    prediction = network.predict(wp.to_torch(p0)[:count], wp.to_torch(p1)[:count],
                                 wp.to_torch(rest_length)[:count], grid.voxel_size)
    tensors = {"hit": prediction["hit"].to(torch.int32),
               "fraction": prediction["fraction"].to(torch.float64),
               "normal": prediction["normal"].to(torch.float64),
               "material": prediction["material"].to(torch.int64)}
    has_albedo = "albedo" in prediction
    tensors["albedo"] = (prediction["albedo"].to(torch.float32) if has_albedo
                         else torch.zeros((1, 3), device=tensors["hit"].device))
    view = kernel.Prediction()
    for name, dtype in (("hit", wp.int32), ("fraction", wp.float64), ("normal", wp.vec3d),
                        ("material", wp.int64), ("albedo", wp.vec3)):
        setattr(view, name, wp.from_torch(tensors[name].contiguous(), dtype=dtype))
    view.table = table
    wp.launch(kernel.first_hits, dim=count, inputs=[buffer, view, first], device=device)
    wp.launch(kernel.resolve, dim=walk.count,
              inputs=[walk.cells.arrays, walk.state, walk.active, buffer, view, first,
                      int(has_albedo), passes], device=device)


def _torch_stream(device):
    """On CUDA, Warp launches go to torch's current stream, so the network reads what the
    walk wrote and the resolve reads what the network wrote, in order."""
    if torch.device(device).type == "cuda":
        return wp.ScopedStream(wp.stream_from_torch(torch.cuda.current_stream(device)))
    return contextlib.nullcontext()


def predict_segments(network, grid, segments, device):
    """``network.predict`` of host Segments (rest-space end points normalized to the grid)."""
    rest_length = np.linalg.norm(segments.p1 - segments.p0, axis=1)
    return network.predict(_tensor(grid.normalize(segments.p0), device),
                           _tensor(grid.normalize(segments.p1), device),
                           _tensor(rest_length, device), grid.voxel_size)


def _tensor(array, device):
    return torch.as_tensor(np.asarray(array, np.float32), device=device)
