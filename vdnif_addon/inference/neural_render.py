"""Neural rendering of the passes (DESIGN section 9): the deformed walk and the network in
waves, so that a ray is walked and evaluated only up to its first predicted hit.

Every ray keeps its walker state on the device (``kernels.walk.RayWalk``). A wave walks each
unresolved ray on by at most k segments (one kernel launch), the network evaluates the wave's
segments in one batch, and a kernel places each ray's hit on its first candidate segment and
makes it a hit at its first confident one (``kernels/render.py``), ending its walk; finished
rays leave the list on the device, and a walker paused before a seek makes it then, so that
a ray that hit spares the cast. Two counts per wave come back to the host, to size the
network batch and the next launch, and the network reads which segments are candidates
(``predict``): on CUDA each read waits for the queued work. With ``waves_per_read`` N > 1
the host reads one count every N waves instead: in between, each launch and the network
batch are sized by the count last read (a wave of k segments per ray gets room for k per
ray), the kernels skip the slots past the device's own counts, and the network also answers
the empty slots and evaluates its point fields at every segment. A frame then reads its
lanes' counts ceil(waves / N) times and its passes once, at the cost of the network run on
that room rather than on the segments walked (``docs/performance.md``, CUDA). A wave holds
at most ``limits.MAX_WAVE_SEGMENTS`` segments: beyond it a ray walks fewer segments, and
past one per ray only part of the rays walk on (the walk pauses the others when the buffer
is full); a ray's passes depend only on its own segments in walk order, so the split
changes nothing but the number of waves.

On the CPU the rays are split into lanes, one per core (``threads.walk_lanes``): a Warp CPU
launch runs on one thread, and so, at one torch thread, does a small batch's MLP. Each lane
renders its own rays wave after wave on a thread of its own (walk, network, resolve), beside
the others, its MLP on its share of the cores and its encoder on its own thread
(``threads.lane_cores``): while one lane runs its MLP, another walks. The lanes hold
disjoint rays and write disjoint memory (``kernels.launches`` says why such launches may run
together); a ray's passes are the same in any lane but for the rounding of the network's
batch, which holds its lane's segments. Torch runs a lane's batch on at most
``threads.RENDER_TORCH_THREADS`` threads.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import warp as wp

from .. import limits, threads
from ..errors import VDNIFError
from ..kernels import launches, runtime
from ..kernels import render as kernel
from ..kernels.segments import segment_buffer
from ..kernels.walk import RayWalk
from ..memory import CPU_RENDER_ADVICE, RENDER_ADVICE, out_of_memory
from ..passes import Passes

if TYPE_CHECKING:
    from jaxtyping import Float, Int

    from ..geometry.voxels import VoxelGrid
    from ..geometry.walk_rules import Segments
    from ..kernels.cells import DeviceCells
    from ..model.network import IntersectionNetwork

    Prediction = tuple[dict[str, torch.Tensor], bool]
    """A wave's predictions as the resolve kernel reads them (hit, candidate, fraction, normal,
    material, albedo: (count, ...) tensors) and whether the model has an albedo head."""

# Segments per ray and wave: k for wave w (w = 0, 1, ...). A wave costs a fixed overhead
# (launches, one network call: about 1 ms on a CPU core) and every segment past a ray's hit
# in its wave is evaluated for nothing. Most rays that hit, hit within their first cells,
# while rays that survive a few waves mostly pass through the object and need all their
# cells: k grows. Measured on a trained bunny, 256x256: k = 1 throughout takes 21 waves and
# 44.7 k segments, this schedule 6 waves and 49.6 k (k = 2, 4, 8, 16: 4 waves, 56.4 k).
WAVE_SEGMENTS = (1, 1, 2, 4, 8, 16)

WAVE_FLOOR = 1024
"""Segments a wave may hold at least: where few rays are left, each walks up to this share
of them in the wave (more than the schedule's k), since the wave's fixed cost outweighs the
network's on that many segments (about 0.7 ms on a CPU core). A secondary pass's walks past
the surface a ray leaves are a few rays each, which the schedule alone walks in 4-5 waves; a
primary pass's waves hold more than this, so it is unchanged."""


def wave_segments(wave: int, schedule: Sequence[int] = WAVE_SEGMENTS) -> int:
    """k of wave ``wave``: the schedule's entry, its last one beyond it."""
    return schedule[min(wave, len(schedule) - 1)]


@dataclass(frozen=True)
class WalkPast:
    """Rays that leave a surface walk on past it where they meet it again from below (DESIGN
    section 9): a ray's hit within its reach and within ``within`` local units of its origin
    (what it walked past included), whose normal's dot product with its row of ``leaving``
    (N, 3, the unit normals of the surfaces the rays leave) exceeds ``cosine``, starts the
    ray again ``step`` past that hit, in the hit's cell, at most ``times`` times."""

    leaving: Float[np.ndarray, "N 3"]
    within: float
    step: float
    cosine: float
    times: int


def neural_passes(network: IntersectionNetwork, grid: VoxelGrid,
                  albedo_table: Float[np.ndarray, "M 3"], cells: DeviceCells,
                  origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"],
                  device: str | torch.device = "cpu", schedule: Sequence[int] = WAVE_SEGMENTS,
                  lanes: int | None = None,
                  max_wave_segments: int = limits.MAX_WAVE_SEGMENTS,
                  max_distance: float | Float[np.ndarray, " N"] | None = None,
                  waves_per_read: int = 1, wave_floor: int = WAVE_FLOOR,
                  start_cells: Int[np.ndarray, " N"] | None = None,
                  walk_past: WalkPast | None = None
                  ) -> tuple[Passes, dict[str, Any]]:
    """(Passes, stats) predicted by ``network`` for rays (N, 3) in the object's deformed
    space, walked through ``cells`` (a ``kernels.cells.DeviceCells`` in the pose).

    A ray hits when one of its segments has an occlusion probability above the model's
    occlusion threshold; its hit lies on its first segment above the lower candidate
    threshold (``network.thresholds``, both calibrated in training): distance
    ``t0 + fraction * l``, normal by ``J^-T``, albedo from the albedo head or, without one,
    from ``albedo_table`` (M, 3) by material. ``device`` is the
    network's torch device; the cells' Warp device must be the same. The rays are walked in
    ``lanes`` lanes at once (default ``threads.walk_lanes``). A wave walks at most
    ``max_wave_segments`` segments, its lanes' share each.
    ``max_distance`` ends the walk (``traverse``): a hit beyond it in the cell that crosses it
    is still reported. ``waves_per_read`` is how many waves a lane renders between host
    reads of its count (the module's docstring); the passes are the same at any value, and at
    any ``wave_floor``, the segments a wave may hold at least where its rays are few
    (``WAVE_FLOOR``; 0: the schedule's k alone). ``start_cells`` (N,) names the cell each
    ray is thought to start in (-1: none), as ``traverse`` takes them; the passes'
    ``cell`` is the cell of each hit. With ``walk_past`` a ray that meets the surface it
    left starts again past it, within the same waves: its distance then counts from where
    it started again, ``stats["walked"]`` (N,) past its origin.
    Running out of memory is a VDNIFError saying what to lower.
    """
    weights = next(iter(network.parameters()), None)
    if weights is not None and runtime.device(weights.device) != runtime.device(device):
        # A mismatch would reach a raw kernel launch, where it is an illegal memory access
        # that poisons the whole session on a GPU: refuse it before any launch.
        raise VDNIFError(f"the network's weights are on {weights.device} but the render runs "
                         f"on {device}: move the network to {device} first")
    warp_device = cells.device
    if runtime.device(device) != runtime.device(warp_device):
        raise VDNIFError(f"the network runs on {device} but the cells are on {warp_device}: "
                         "render with both on one device")
    runtime.load(kernel.WARP_MODULE, warp_device)
    rays = len(origins)
    lanes = threads.walk_lanes(device, rays) if lanes is None else lanes
    if lanes < 1:
        raise VDNIFError(f"a render walks at least one lane, not {lanes}")
    if waves_per_read < 1:
        raise VDNIFError(f"a render reads its counts every 1 or more waves, not {waves_per_read}")
    torch_threads = max(1, min(threads.RENDER_TORCH_THREADS, threads.cores() // lanes))
    with (out_of_memory("rendering", RENDER_ADVICE, CPU_RENDER_ADVICE), _device_stream(device),
          threads.torch_threads_at_most(torch_threads)):
        walk = RayWalk(cells, origins, directions, max_distance, lanes=lanes,
                       start_cells=start_cells)
        past = kernel.never_walk_past(str(warp_device)) if walk_past is None else (
            kernel.walk_past(walk_past.leaving, origins, directions,
                             np.broadcast_to(np.asarray(np.inf if max_distance is None
                                                        else max_distance, np.float64),
                                             (rays,)),
                             walk_past.within, walk_past.step, walk_past.cosine,
                             walk_past.times, warp_device))
        waves = _Waves(network, grid, walk, schedule, albedo_table,
                       max(1, max_wave_segments // lanes), waves_per_read, wave_floor, past)
        share = max(1, threads.cores() // lanes)
        encoder = None if lanes == 1 else 1
        lane_stats = threads.at_once(lambda lane: _render_lane(waves, lane, share, encoder),
                                     lanes, "vdnif-lane")
        stats = {"waves": max(s["waves"] for s in lane_stats),
                 **{name: sum(s[name] for s in lane_stats) / lanes
                    for name in ("walk_s", "network_s")}}
        totals = waves.totals           # the truncated rays, then each lane's segments
        if rays:
            wp.launch(kernel.clear_misses, dim=rays, inputs=[waves.passes], device=warp_device)
            wp.launch(kernel.unresolved_truncated, dim=rays,
                      inputs=[walk.state, waves.passes, totals], device=warp_device)
        totals = totals.numpy()
        stats["truncated"], stats["segments"] = int(totals[0]), int(totals[1:].sum())
        if walk_past is not None:
            stats["walked"] = (past.walked.numpy() if walk_past.times and rays
                               else np.zeros(rays))
        passes = waves.passes
        result = Passes(hit=passes.hit.numpy().astype(bool), distance=passes.distance.numpy(),
                        normal=passes.normal.numpy(), albedo=passes.albedo.numpy(),
                        material=passes.material.numpy(), cell=passes.cell.numpy())
    return result, stats


def _render_lane(waves: _Waves, lane: int, cores: int, encoder: int | None
                 ) -> dict[str, float]:
    """Renders ``lane`` wave by wave (walk, network, resolve) until its rays are done, on
    this thread with ``cores`` cores of its own and its encoder split over ``encoder``
    threads (``threads.lane_cores``); returns its waves and the seconds it spent walking
    (with the drop of finished rays and their paused seeks) and in the network (with the
    resolve). Its count is read every ``waves.per_read``
    waves."""
    stats = dict(waves=0, walk_s=0.0, network_s=0.0)
    rays = waves.walk.lanes[lane]
    with threads.lane_cores(cores, encoder):
        while rays.count:
            for _ in range(waves.per_read):
                clock = time.perf_counter()
                count = waves.advance(lane)
                walked = time.perf_counter()
                waves.resolve(lane, count, waves.predict(lane, count))
                resolved = time.perf_counter()
                waves.walk.drop_finished(lane, read=waves.per_read == 1)
                stats["walk_s"] += walked - clock + time.perf_counter() - resolved
                stats["network_s"] += resolved - walked
                stats["waves"] += 1
                if not rays.count:
                    break
            if waves.per_read > 1:
                waves.walk.read_count(lane)
    return stats


class _Waves:
    """The three steps of a lane's wave: ``advance`` (Warp only: the walk kernel and the
    network inputs), ``predict`` of its segments in one batch (the network: the Warp encoder
    and torch's MLP), ``resolve`` (Warp: hits placed and made); the lane's loop then drops
    its finished rays (``RayWalk.drop_finished``, timed as walking). Different
    lanes' steps run at once."""

    def __init__(self, network: IntersectionNetwork, grid: VoxelGrid, walk: RayWalk,
                 schedule: Sequence[int], albedo_table: Float[np.ndarray, "M 3"],
                 max_segments: int, per_read: int, floor: int,
                 past: kernel.WalkPast) -> None:
        self.network, self.grid, self.walk, self.schedule = network, grid, walk, schedule
        self.past = past
        self.device, self.max_segments, self.per_read = walk.device, max_segments, per_read
        self.floor = floor
        self.totals = wp.zeros(1 + len(walk.lanes), dtype=wp.int32, device=self.device)
        self.passes = kernel.empty_passes(walk.rays, self.device)
        self.first = wp.full(walk.rays, int(kernel.NO_HIT), dtype=wp.int32, device=self.device)
        self.candidate = wp.full(walk.rays, int(kernel.NO_HIT), dtype=wp.int32,
                                 device=self.device)
        self.placed = wp.zeros(walk.rays, dtype=wp.int32, device=self.device)
        self.table = wp.array(np.asarray(albedo_table, np.float32).reshape(-1, 3),
                              dtype=wp.vec3, device=self.device)
        self.waves = [0] * len(walk.lanes)
        self.buffers = [None] * len(walk.lanes)
        self.inputs = [None] * len(walk.lanes)

    def advance(self, lane: int) -> int:
        """Walks ``lane`` on by its next wave's k segments per ray (more where its rays are
        so few that the wave would hold under ``floor`` segments), fewer where the wave would
        pass ``max_segments``; returns how many segments it walked, read on the host, or
        between reads (``per_read`` > 1) the room it gave them (the rest empty)."""
        rays = self.walk.lanes[lane].count
        per_wave = max(1, min(max(wave_segments(self.waves[lane], self.schedule),
                                  self.floor // rays),
                              self.max_segments // rays))
        self.waves[lane] += 1
        need = min(rays * per_wave, self.max_segments)
        if self.buffers[lane] is None or need > self.buffers[lane].capacity:
            self.buffers[lane] = segment_buffer(need, self.device)
            self.inputs[lane] = [wp.empty(need, dtype=dtype, device=self.device)
                                 for dtype in (wp.vec3, wp.vec3, wp.float32)]
        buffer = self.buffers[lane]
        buffer.cursor.zero_()
        read = self.per_read == 1
        count = self.walk.advance(buffer, per_wave, lane, read)
        count = count if read else need
        wp.launch(kernel.count_segments, dim=1, inputs=[buffer, self.totals, lane + 1],
                  device=self.device)
        if count:
            wp.launch(kernel.network_inputs, dim=count,
                      inputs=[buffer, wp.vec3d(*self.grid.origin), wp.float64(self.grid.extent),
                              *self.inputs[lane]],
                      device=self.device)
        return count

    def predict(self, lane: int, count: int) -> Prediction | None:
        """The network's predictions for the ``count`` segments of ``lane``'s wave, in one
        batch (None without any)."""
        if not count:
            return None
        p0, p1, rest_length = (wp.to_torch(x)[:count] for x in self.inputs[lane])
        # between reads, the candidates are not found on the host either
        device_only = {} if self.per_read == 1 else {"select_candidates": False}
        prediction = self.network.predict(p0, p1, rest_length, self.grid.voxel_size,
                                          **device_only)
        has_albedo = "albedo" in prediction
        tensors = {"hit": prediction["hit"].to(torch.int32),
                   "candidate": prediction["candidate"].to(torch.int32),
                   "fraction": prediction["fraction"].to(torch.float64),
                   "normal": prediction["normal"].to(torch.float64),
                   "material": prediction["material"].to(torch.int64),
                   "albedo": (prediction["albedo"].to(torch.float32) if has_albedo
                              else p0.new_zeros((1, 3)))}
        return {name: value.contiguous() for name, value in tensors.items()}, has_albedo

    def resolve(self, lane: int, count: int, prediction: Prediction | None) -> None:
        """Each ray's first candidate segment, unless one is placed already, into its passes,
        and a ray with a segment above the occlusion threshold made a hit (its walk ends
        there)."""
        if count:
            tensors, has_albedo = prediction
            view = kernel.Prediction()
            for name, dtype in (("hit", wp.int32), ("candidate", wp.int32),
                                ("fraction", wp.float64),
                                ("normal", wp.vec3d), ("material", wp.int64),
                                ("albedo", wp.vec3)):
                setattr(view, name, wp.from_torch(tensors[name], dtype=dtype))
            view.table = self.table
            buffer, rays = self.buffers[lane], self.walk.lanes[lane]
            wp.launch(kernel.first_hits, dim=count,
                      inputs=[buffer, view, self.first, self.candidate], device=self.device)
            wp.launch(kernel.resolve, dim=rays.count,
                      inputs=[self.walk.cells.arrays, self.walk.state, rays.active,
                              rays.active_count, buffer, view, self.first, self.candidate,
                              self.placed,
                              int(has_albedo), self.passes, self.past],
                      device=self.device)




@contextlib.contextmanager
def _device_stream(device: str | torch.device) -> Iterator[None]:
    """On CUDA the render runs on the device's default stream, after the work the caller's
    current stream holds and before its later work. Warp's launches and torch's (the
    network) then run in order, and Warp's host reads (a wave's counts, the passes), which
    copy on the default stream, wait for them: under ``torch.cuda.stream`` the caller's
    stream does not synchronize with that copy."""
    device = torch.device(device)
    if device.type != "cuda":
        yield
        return
    caller = torch.cuda.current_stream(device)
    default = torch.cuda.default_stream(device)
    default.wait_stream(caller)
    try:
        with torch.cuda.stream(default), wp.ScopedStream(launches.warp_stream(default)):
            yield
    finally:
        caller.wait_stream(default)


def predict_segments(network: IntersectionNetwork, grid: VoxelGrid, segments: Segments,
                     device: str | torch.device) -> dict[str, torch.Tensor]:
    """``network.predict`` of host Segments (rest-space end points normalized to the grid)."""
    rest_length = np.linalg.norm(segments.p1 - segments.p0, axis=1)
    return network.predict(_tensor(grid.normalize(segments.p0), device),
                           _tensor(grid.normalize(segments.p1), device),
                           _tensor(rest_length, device), grid.voxel_size)


def _tensor(array: Float[np.ndarray, "*batch"], device: str | torch.device
            ) -> Float[torch.Tensor, "*batch"]:
    return torch.as_tensor(np.asarray(array, np.float32), device=device)
