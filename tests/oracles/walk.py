"""The numpy wavefront walk through deformed cells: the test oracle of the walk kernel
(``vdnif_addon/kernels/walk.py``).

This is the walk the product ran before the kernel replaced it, with the same rules (DESIGN
section 5), plus the bound on re-seeks the kernel has too: a seek that meets more than
``walk_rules.SEEK_LIMIT`` faces in a row that the ray leaves by gives the ray up, and rays
given up count as truncated. Every walker advances one cell per ``advance()`` (rays all start
together, so the global step count is every ray's own step count).
"""

import numpy as np

from oracles.geometry import _crossings, _dot, entry_cast, ray_triangle
from vdnif_addon.geometry.walk_rules import (
    CELL_TRIANGLES,
    OPPOSITE_FACE,
    SEEK_LIMIT,
    ZERO_PASS_LIMIT,
    Segments,
    step_budget,
)

WALK_CHUNK = 1 << 14             # walkers per vectorized intersection batch (bounds memory)


class DeformedCells:
    """The occupied cells of one pose as numpy arrays: rest and deformed corners per cell,
    the face-neighbour table and the boundary triangles (the rows of the entry caster)."""

    def __init__(self, grid, deformed_corners):
        """From a VoxelGrid and (C, 3) deformed corner positions of one pose."""
        self.rest_corners = grid.corner_positions()[grid.cell_corners]        # (N, 8, 3)
        self.corners = np.asarray(deformed_corners, np.float64)[grid.cell_corners]
        self.neighbours = grid.neighbours.astype(np.int64)                     # (N, 6)
        cell, face = np.nonzero(grid.neighbours < 0)
        self.boundary_cell = np.repeat(cell, 2)                                # (K,)
        self.boundary_triangle = (2 * face[:, None] + np.arange(2)).ravel()    # (K,) 0..11
        a, b, c = (np.moveaxis(self.corners[:, CELL_TRIANGLES[:, k]], -1, 0) for k in range(3))
        e1, e2 = b - a, c - a
        # (N, 10, 12): a, e1, e2 (x, y, z rows each), |e1| |e2|
        self.triangles = np.concatenate(
            [a, e1, e2, np.sqrt(_dot(e1, e1) * _dot(e2, e2))[None]]).transpose(1, 0, 2).copy()

    def boundary_triangles(self):
        """(K, 3, 3) deformed corners of the boundary triangles."""
        local = CELL_TRIANGLES[self.boundary_triangle]
        return self.corners[self.boundary_cell[:, None], local]

    def rest_point(self, cell, triangle, u, v):
        """(M, 3) rest-space point with barycentric (u, v) on a cell's face triangle."""
        local = CELL_TRIANGLES[triangle]
        a, b, c = (self.rest_corners[cell, local[:, k]] for k in range(3))
        u, v = np.clip(u, 0, 1)[:, None], np.clip(v, 0, 1)[:, None]
        scale = np.maximum(u + v, 1.0)
        return a + (b - a) * (u / scale) + (c - a) * (v / scale)


def traverse(cells, entry_caster, origins, directions, max_distance=None, max_steps=None,
             step=None):
    """All rest-space Segments of the rays, ordered by ray then distance."""
    walk = Walk(cells, entry_caster, origins, directions, max_distance, step)
    walk.run(max_steps)
    return walk.segments()


class Walk:
    """The wavefront: every active ray walks one cell per ``advance()``; ``take_new()`` gives
    the segments of the last steps and ``stop(rays)`` ends rays (the old neural renderer)."""

    def __init__(self, cells, caster, origins, directions, max_distance=None, step=None):
        origins = np.asarray(origins, np.float64)
        directions = np.asarray(directions, np.float64)
        norms = np.linalg.norm(directions, axis=1)
        self.directions = directions / np.where(norms > 0, norms, 1.0)[:, None]
        rays = len(origins)
        self.far = np.full(rays, np.inf) if max_distance is None else np.broadcast_to(
            np.asarray(max_distance, np.float64), (rays,)).copy()
        self.far[norms == 0] = -1.0                                 # no direction: no hit
        cell_size = float(np.linalg.norm(cells.rest_corners[0, 7] - cells.rest_corners[0, 0]))
        scene_size = float(np.ptp(cells.corners.reshape(-1, 3), axis=0).max()) or 1.0
        self.step = 1e-6 * max(scene_size, cell_size) if step is None else step
        self.default_steps = step_budget(len(cells.corners))
        self.cells, self.caster, self.origins = cells, caster, origins
        empty_i, empty_f = np.empty(0, np.int64), np.empty(0)
        self.ray, self.cell, self.entry_face = empty_i, empty_i, empty_i
        self.t_in, self.p_in, self.zero_passes = empty_f, np.empty((0, 3)), empty_i
        self.clip_from = np.zeros(rays)                   # < 0 for rays starting inside
        self.behind_from = np.full(rays, -np.inf)         # seek start of the last entry behind
        self.pieces, self.taken, self.steps, self.given_up = [], 0, 0, 0
        self.seek(np.arange(rays), np.zeros(rays), first=True)


    def _cast(self, origins, directions, max_distance):
        """The entry caster's first hits: a DeviceCells' entry BVH (as the kernel casts), or
        any caster with a ``cast`` of that signature (the brute-force one)."""
        if hasattr(self.caster, "entry"):
            return entry_cast(self.caster, origins, directions, max_distance)
        return self.caster.cast(origins, directions, max_distance)
    def active(self):
        return len(self.ray)

    def running(self, max_steps=None):
        return bool(self.active()) and self.steps < (max_steps or self.default_steps)

    def run(self, max_steps=None):
        while self.running(max_steps):
            self.advance()

    def take_new(self):
        pieces, self.taken = self.pieces[self.taken:], len(self.pieces)
        return _segments(pieces)

    def stop(self, rays):
        keep = ~np.isin(self.ray, rays)
        for name in ("ray", "cell", "entry_face", "t_in", "p_in", "zero_passes"):
            setattr(self, name, getattr(self, name)[keep])

    def seek(self, rays, t_from, first=False):
        """Finds where ``rays`` (re-)enter the occupied set at or after ``t_from``; a ray
        still meeting faces it leaves by after SEEK_LIMIT casts is given up."""
        casts = 0
        while len(rays):
            if casts == SEEK_LIMIT:
                self.given_up += len(rays)
                return
            casts += 1
            remaining = self.far[rays] - t_from
            ok = remaining >= 0
            rays, t_from, remaining = rays[ok], t_from[ok], remaining[ok]
            start = self.origins[rays] + t_from[:, None] * self.directions[rays]
            # the first cast looks for the boundary ahead however far: whether it starts inside
            index, t = self._cast(start, self.directions[rays],
                                  np.full(len(rays), np.inf) if first else remaining)
            hit = index >= 0
            rays, index, t_from = rays[hit], index[hit], t_from[hit]
            t, u, v, leaving = self._crossing(rays, index, t[hit] + t_from)
            if first:
                back_index, back_t, back_u, back_v = self._start_inside(rays[leaving])
                found = back_index >= 0                 # else keep the forward crossing
                rows = np.flatnonzero(leaving)[found]
                index[rows], t[rows] = back_index[found], back_t[found]
                u[rows], v[rows] = back_u[found], back_v[found]
                leaving[:] = False
                first = False
                near = t <= self.far[rays]              # else it enters beyond its limit
                rays, index, t, u, v, leaving, t_from = (
                    x[near] for x in (rays, index, t, u, v, leaving, t_from))
            else:
                self._entered_behind(rays, index, t, u, v, leaving, t_from)
            self._enter(rays[~leaving], index[~leaving], t[~leaving], u[~leaving],
                        v[~leaving])
            rays, t_from = rays[leaving], np.maximum(t, t_from)[leaving] + self.step

    def _entered_behind(self, rays, index, t, u, v, leaving, t_from):
        """A leaving crossing more than step beyond the seek start means the start is inside
        the occupied set (a cell across an edge or corner of the cell left begins within step
        of the exit): rows whose entry the backward cast finds within 2 step are entered
        there instead (updates index, t, u, v, leaving in place), only past the seek start
        of the ray's last such entry (a collapsed cell would be entered forever)."""
        inside = np.flatnonzero(leaving & (t > t_from + self.step)
                                & (t_from > self.behind_from[rays]))
        if not len(inside):
            return
        start = self.origins[rays[inside]] + t_from[inside, None] * self.directions[rays[inside]]
        back_index, back_t = self._cast(start, -self.directions[rays[inside]],
                                              np.full(len(inside), 2.0 * self.step))
        found = back_index >= 0
        inside, back_index, back_t = inside[found], back_index[found], back_t[found]
        cross_t, cross_u, cross_v, back_leaving = self._crossing(
            rays[inside], back_index, t_from[inside] - back_t)
        enter = ~back_leaving
        inside = inside[enter]
        index[inside], u[inside], v[inside] = back_index[enter], cross_u[enter], cross_v[enter]
        t[inside] = np.maximum(cross_t[enter], t_from[inside] - self.step)
        leaving[inside] = False
        self.behind_from[rays[inside]] = t_from[inside]

    def _enter(self, rays, index, t, u, v):
        cell = self.cells.boundary_cell[index]
        triangle = self.cells.boundary_triangle[index]
        self._add_walkers(rays, cell, triangle // 2, t,
                          self.cells.rest_point(cell, triangle, u, v))

    def _crossing(self, rays, index, t):
        local = CELL_TRIANGLES[self.cells.boundary_triangle[index]]
        cell = self.cells.boundary_cell[index]
        a, b, c = (self.cells.corners[cell, local[:, k]] for k in range(3))
        exact, u, v, usable, outward = ray_triangle(self.origins[rays], self.directions[rays],
                                                    a, b, c)
        close = usable & (np.abs(exact - t) < 1e-3 * (1 + np.abs(t)))
        return np.where(close, exact, t), u, v, outward

    def _start_inside(self, rays):
        back_index, back_t = self._cast(self.origins[rays], -self.directions[rays],
                                              np.full(len(rays), np.inf))
        found = back_index >= 0
        t, u, v = np.zeros(len(rays)), np.zeros(len(rays)), np.zeros(len(rays))
        t[found], u[found], v[found], _ = self._crossing(rays[found], back_index[found],
                                                         -back_t[found])
        self.clip_from[rays[found]] = t[found]
        return back_index, t, u, v

    def _add_walkers(self, rays, cell, entry_face, t, p, zero_passes=None):
        zero_passes = np.zeros(len(rays), np.int64) if zero_passes is None else zero_passes
        self.ray = np.concatenate([self.ray, rays])
        self.cell = np.concatenate([self.cell, cell])
        self.entry_face = np.concatenate([self.entry_face, entry_face])
        self.t_in = np.concatenate([self.t_in, t])
        self.p_in = np.concatenate([self.p_in, p])
        self.zero_passes = np.concatenate([self.zero_passes, zero_passes])

    def advance(self):
        self.steps += 1
        ray, cell, entry_face = self.ray, self.cell, self.entry_face
        t_in, p_in, zero_passes = self.t_in, self.p_in, self.zero_passes
        self.ray = self.cell = self.entry_face = self.zero_passes = np.empty(0, np.int64)
        self.t_in, self.p_in = np.empty(0), np.empty((0, 3))
        for start in range(0, len(ray), WALK_CHUNK):
            rows = slice(start, start + WALK_CHUNK)
            self._advance_chunk(ray[rows], cell[rows], entry_face[rows], t_in[rows],
                                p_in[rows], zero_passes[rows])

    def _advance_chunk(self, ray, cell, entry_face, t_in, p_in, zero_passes):
        triangles = np.take(self.cells.triangles, cell, axis=0).transpose(1, 0, 2)
        o = self.origins[ray].T[:, :, None]                                # (3, W, 1)
        d = self.directions[ray].T[:, :, None]
        t, u, v, hit, outward = _crossings(o, d, triangles[0:3], triangles[3:6],
                                           triangles[6:9], triangles[9])    # (W, 12)
        far_side = np.where(hit & (t > t_in[:, None]), t, -np.inf).max(1)
        hit &= outward & ((np.arange(12) // 2)[None] != entry_face[:, None])
        ahead = hit & (t > t_in[:, None] + self.step)
        touching = hit & (t >= t_in[:, None] - self.step)
        has_ahead = ahead.any(1)
        exit_triangle = np.where(has_ahead, np.where(ahead, t, np.inf).argmin(1),
                                 np.where(touching, t, -np.inf).argmax(1))
        lost = ~touching.any(1)
        rows = np.arange(len(ray))
        # a lost walker (nothing touched) has no exit: its t stays, and it re-seeks below
        t_out = np.where(lost, t_in, np.maximum(t[rows, exit_triangle], t_in))
        p_out = self.cells.rest_point(cell, exit_triangle, u[rows, exit_triangle],
                                      v[rows, exit_triangle])
        beyond = t_out <= self.far[ray]
        record = has_ahead & (t_in <= self.far[ray])    # the cell crossing the limit whole
        self._record(ray[record], cell[record], t_in[record], t_out[record],
                     p_in[record], p_out[record])
        exit_face = exit_triangle // 2
        neighbour = self.cells.neighbours[cell, exit_face]
        zero_passes = np.where(has_ahead, 0, zero_passes + 1)
        go_on = ~lost & beyond & (neighbour >= 0) & (zero_passes <= ZERO_PASS_LIMIT)
        self._add_walkers(ray[go_on], neighbour[go_on], OPPOSITE_FACE[exit_face[go_on]],
                          t_out[go_on], p_out[go_on], zero_passes[go_on])
        reseek = ~go_on & beyond
        self.seek(ray[reseek], np.where(lost, np.maximum(far_side, t_in), t_out)[reseek]
                  + self.step)

    def _record(self, ray, cell, t0, t1, p0, p1):
        clip = self.clip_from[ray] < 0
        if clip.any():                                 # rays that started inside: cut at 0
            keep = ~clip | (t1 > 0)
            ray, cell, t0, t1, p0, p1 = (x[keep] for x in (ray, cell, t0, t1, p0, p1))
            cut = (t0 < 0)
            fraction = np.where(cut, -t0 / np.where(cut, t1 - t0, 1.0), 0.0)[:, None]
            p0 = p0 + fraction * (p1 - p0)
            t0 = np.maximum(t0, 0.0)
        self.pieces.append((ray, cell, t0, t1, p0, p1))

    def segments(self):
        return _segments(self.pieces, truncated=self.active() + self.given_up)


def _segments(pieces, truncated=0):
    if pieces:
        ray, cell, t0, t1, p0, p1 = (np.concatenate(x) for x in zip(*pieces))
    else:
        ray = cell = np.empty(0, np.int64)
        t0 = t1 = np.empty(0)
        p0 = p1 = np.empty((0, 3))
    order = np.lexsort((t0, ray))
    return Segments(ray=ray[order], cell=cell[order], t0=t0[order], t1=t1[order],
                    p0=p0[order], p1=p1[order], truncated=int(truncated))
