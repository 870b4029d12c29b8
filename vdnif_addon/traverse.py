"""Traversal in deformed space (DESIGN sections 5 and 6).

A deformed cell is its 8 deformed corners; each face is split into two triangles along the
diagonal from its lowest to its highest lattice corner, so a face shared by two cells is split
identically and the cell complex is watertight. Rays enter the occupied set through its
boundary triangles (found by a ray caster, e.g. a BVH), then walk from cell to cell through
exit faces: one vectorized step per voxel layer for all rays at once. Every crossing point
lies on a face triangle; its barycentric coordinates on the same rest-space triangle give the
exact rest-space point, so each walked cell yields a rest-space segment ``(p0, p1)``.
"""

import time
from dataclasses import dataclass

import numpy as np

# Faces in the neighbour-table order -x, +x, -y, +y, -z, +z; corner c = dx + 2 dy + 4 dz.
FACE_AXIS = np.array([0, 0, 1, 1, 2, 2])
FACE_SIDE = np.array([0, 1, 0, 1, 0, 1])
OPPOSITE_FACE = np.array([1, 0, 3, 2, 5, 4])
BARYCENTRIC_TOLERANCE = 1e-7     # inclusive triangle edges: no ray leaks between triangles
ZERO_PASS_LIMIT = 8              # zero-length passes in a row before re-seeking the entry
WALK_CHUNK = 1 << 14             # walkers per vectorized intersection batch (bounds memory)


def _face_triangles():
    """(6, 2, 3) corner numbers of each face's two triangles, wound so that the rest-space
    normal points out of the cell, split along the lowest-highest corner diagonal."""
    triangles = np.empty((6, 2, 3), np.int64)
    for face in range(6):
        axis, side = FACE_AXIS[face], FACE_SIDE[face]
        u, v = (axis + 1) % 3, (axis + 2) % 3

        def corner(du, dv):
            offset = np.zeros(3, np.int64)
            offset[axis], offset[u], offset[v] = side, du, dv
            return int(offset @ (1, 2, 4))

        a00, a10, a11, a01 = corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)
        pair = [[a00, a10, a11], [a00, a11, a01]]      # normal along +axis
        triangles[face] = pair if side == 1 else [t[::-1] for t in pair]
    return triangles


FACE_TRIANGLES = _face_triangles()
CELL_TRIANGLES = FACE_TRIANGLES.reshape(12, 3)         # triangle k belongs to face k // 2


@dataclass
class Segments:
    """Per-voxel pieces of rays, ordered by ray then by distance along it.

    ``t0``/``t1`` are distances along the (unit-direction) deformed ray at the entry and exit
    of the cell: deformed length ``l = t1 - t0``, gap ``delta = t0 - t1`` of the previous
    segment of the same ray (or ``t0`` for the first one).
    """

    ray: np.ndarray        # (S,) int64
    cell: np.ndarray       # (S,) int64 index into grid.cells
    t0: np.ndarray         # (S,) float64
    t1: np.ndarray         # (S,) float64
    p0: np.ndarray         # (S, 3) float64 rest-space entry point
    p1: np.ndarray         # (S, 3) float64 rest-space exit point
    truncated: int = 0     # rays stopped by the step limit (should stay 0)

    def __len__(self):
        return len(self.ray)

    @property
    def length(self):
        return self.t1 - self.t0

    @property
    def gap(self):
        """(S,) delta: distance from the previous segment's exit (or the ray origin)."""
        previous_exit = np.zeros_like(self.t0)
        same_ray = np.zeros(len(self.ray), bool)
        same_ray[1:] = self.ray[1:] == self.ray[:-1]
        previous_exit[1:] = np.where(same_ray[1:], self.t1[:-1], 0.0)
        return self.t0 - previous_exit

    def first_per_ray(self, mask, rays):
        """(rays,) index of the first segment of each ray where ``mask`` holds, or -1."""
        first = np.full(rays, -1, np.int64)
        hits = np.flatnonzero(mask)[::-1]          # reversed: the earliest write wins last
        first[self.ray[hits]] = hits
        return first


def ray_triangle(origins, directions, a, b, c):
    """Möller-Trumbore for matching (broadcast) rows: origins/directions (..., 3), triangle
    corners (..., 3). Returns (t, u, v, hit, outward): distance, barycentric weights of b and
    c, whether the ray's line crosses the triangle (edges inclusive; parallel rays never
    hit), and whether it crosses along the triangle's normal ``(b - a) x (c - a)``."""
    o, d, a, b, c = (np.moveaxis(x, -1, 0) for x in (origins, directions, a, b, c))
    return _crossings(o, d, a, b - a, c - a)


def _crossings(o, d, a, e1, e2, scale=None):
    """Möller-Trumbore on x, y, z components held apart (leading axis of length 3): several
    times faster than ``np.cross`` and ``sum(-1)`` on small trailing axes, which matters
    since the walk lives here. ``scale`` = |e1| |e2| may be given precomputed."""
    p = _cross(d, e2)
    det = _dot(e1, p)
    scale = np.sqrt(_dot(e1, e1) * _dot(e2, e2)) if scale is None else scale
    usable = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    inv = np.where(usable, 1.0 / np.where(usable, det, 1.0), 0.0)
    s = o - a
    u = _dot(s, p) * inv
    q = _cross(s, e1)
    v = _dot(d, q) * inv
    t = _dot(e2, q) * inv
    tol = BARYCENTRIC_TOLERANCE
    hit = usable & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol)
    return t, u, v, hit, det < 0


def _cross(x, y):
    return (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])


def _dot(x, y):
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


class BruteForceCaster:
    """First hit of rays against a triangle soup by testing every triangle: the reference
    caster for tests and the fallback where no BVH is available."""

    def __init__(self, triangles):
        """``triangles``: (K, 3, 3) corner positions."""
        self.triangles = np.asarray(triangles, np.float64)

    def cast(self, origins, directions, max_distance):
        """(index (N,) int64, -1 on a miss; t (N,)): first hit with 0 <= t <= max_distance."""
        n = len(origins)
        index, best = np.full(n, -1, np.int64), np.full(n, np.inf)
        a, b, c = (self.triangles[None, :, k] for k in range(3))
        for start in range(0, n, 256):
            rows = slice(start, start + 256)
            t, _, _, hit, _ = ray_triangle(origins[rows, None], directions[rows, None], a, b, c)
            t = np.where(hit & (t >= 0) & (t <= max_distance[rows, None]), t, np.inf)
            index[rows] = np.where(np.isfinite(t.min(1)), t.argmin(1), -1)
            best[rows] = t.min(1)
        return index, np.where(index >= 0, best, np.inf)


class TimedCaster:
    """Wraps a caster and adds up the seconds spent in it, for throughput reports."""

    def __init__(self, caster):
        self.caster, self.seconds = caster, 0.0

    def cast(self, origins, directions, max_distance):
        start = time.perf_counter()
        result = self.caster.cast(origins, directions, max_distance)
        self.seconds += time.perf_counter() - start
        return result


@dataclass
class DeformedCells:
    """The occupied cells of one pose: rest and deformed corners plus the boundary triangles
    through which rays enter the occupied set."""

    rest_corners: np.ndarray       # (N, 8, 3) float64 per cell
    corners: np.ndarray            # (N, 8, 3) float64 deformed, per cell
    neighbours: np.ndarray         # (N, 6) int64, -1 where empty
    boundary_cell: np.ndarray      # (K,) int64
    boundary_triangle: np.ndarray  # (K,) int64 in 0..11
    triangles: np.ndarray = None   # (N, 10, 12): a, e1, e2 (x, y, z rows each), |e1| |e2|

    @classmethod
    def build(cls, grid, deformed_corners):
        """From a VoxelGrid and (C, 3) deformed corner positions of one pose."""
        rest = grid.corner_positions()[grid.cell_corners]
        corners = np.asarray(deformed_corners, np.float64)[grid.cell_corners]
        cell, face = np.nonzero(grid.neighbours < 0)
        a, b, c = (np.moveaxis(corners[:, CELL_TRIANGLES[:, k]], -1, 0) for k in range(3))
        e1, e2 = b - a, c - a
        return cls(rest_corners=rest, corners=corners,
                   neighbours=grid.neighbours.astype(np.int64),
                   boundary_cell=np.repeat(cell, 2),
                   boundary_triangle=(2 * face[:, None] + np.arange(2)).ravel(),
                   triangles=np.concatenate([a, e1, e2, np.sqrt(_dot(e1, e1) * _dot(e2, e2))[None]])
                   .transpose(1, 0, 2).copy())

    def boundary_triangles(self, index=slice(None)):
        """(K, 3, 3) deformed corners of the boundary triangles, for the entry caster."""
        local = CELL_TRIANGLES[self.boundary_triangle[index]]
        return self.corners[self.boundary_cell[index][:, None], local]

    def rest_point(self, cell, triangle, u, v):
        """(M, 3) rest-space point with barycentric (u, v) on a cell's face triangle."""
        local = CELL_TRIANGLES[triangle]
        a, b, c = (self.rest_corners[cell, local[:, k]] for k in range(3))
        u, v = np.clip(u, 0, 1)[:, None], np.clip(v, 0, 1)[:, None]
        scale = np.maximum(u + v, 1.0)
        return a + (b - a) * (u / scale) + (c - a) * (v / scale)


def traverse(cells, entry_caster, origins, directions, max_distance=None, max_steps=None):
    """Walks rays through the deformed cells and returns all their rest-space Segments.

    ``entry_caster.cast(origins, directions, max_distance)`` finds the first boundary
    triangle (index into ``cells.boundary_triangles()``) along each ray. ``directions`` are
    normalized here; ``t`` is measured in the units of ``origins``.
    """
    walk = Walk(cells, entry_caster, origins, directions, max_distance)
    walk.run(max_steps)
    return walk.segments()


class Walk:
    """The wavefront: every active ray walks one cell per ``advance()``.

    ``traverse`` runs it to the end; the neural renderer steps it, reads each step's new
    segments (at most one per ray) with ``take_new()`` and ``stop``s the rays it resolved,
    so a ray is walked and evaluated only up to its hit.
    """

    def __init__(self, cells, caster, origins, directions, max_distance=None):
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
        self.step = 1e-6 * max(scene_size, cell_size)
        self.default_steps = 4 * len(cells.corners) + 64
        self.cells, self.caster, self.origins = cells, caster, origins
        empty_i, empty_f = np.empty(0, np.int64), np.empty(0)
        self.ray, self.cell, self.entry_face = empty_i, empty_i, empty_i
        self.t_in, self.p_in, self.zero_passes = empty_f, np.empty((0, 3)), empty_i
        self.clip_from = np.zeros(rays)                   # < 0 for rays starting inside
        self.pieces, self.taken, self.steps = [], 0, 0
        self.seek(np.arange(rays), np.zeros(rays), first=True)

    def active(self):
        return len(self.ray)

    def running(self, max_steps=None):
        """True while rays are active and fewer than ``max_steps`` (default: four per used
        corner) steps were made: a bound that no terminating walk reaches."""
        return bool(self.active()) and self.steps < (max_steps or self.default_steps)

    def run(self, max_steps=None):
        """Advances until no ray is active or ``max_steps`` steps were made."""
        while self.running(max_steps):
            self.advance()

    def take_new(self):
        """Segments recorded since the last call (at most one per ray and step)."""
        pieces, self.taken = self.pieces[self.taken:], len(self.pieces)
        return _segments(pieces)

    def stop(self, rays):
        """Ends the walk of ``rays`` (e.g. resolved by the network)."""
        keep = ~np.isin(self.ray, rays)
        for name in ("ray", "cell", "entry_face", "t_in", "p_in", "zero_passes"):
            setattr(self, name, getattr(self, name)[keep])

    def seek(self, rays, t_from, first=False):
        """Finds where ``rays`` (re-)enter the occupied set at or after ``t_from``.

        A hit on a boundary face the ray leaves by (a float32 caster may report the face just
        exited) is skipped by seeking again beyond it; on the first seek it means the ray
        starts inside the occupied set.
        """
        while len(rays):
            remaining = self.far[rays] - t_from
            ok = remaining >= 0
            rays, t_from, remaining = rays[ok], t_from[ok], remaining[ok]
            start = self.origins[rays] + t_from[:, None] * self.directions[rays]
            index, t = self.caster.cast(start, self.directions[rays], remaining)
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
            self._enter(rays[~leaving], index[~leaving], t[~leaving], u[~leaving],
                        v[~leaving])
            rays, t_from = rays[leaving], np.maximum(t, t_from)[leaving] + self.step

    def _enter(self, rays, index, t, u, v):
        cell = self.cells.boundary_cell[index]
        triangle = self.cells.boundary_triangle[index]
        self._add_walkers(rays, cell, triangle // 2, t,
                          self.cells.rest_point(cell, triangle, u, v))

    def _crossing(self, rays, index, t):
        """Where rays cross the boundary triangles a caster reported at ``t``: float64
        distance (a float32 caster's ``t`` refined), barycentric (u, v), and whether the ray
        leaves the occupied set there (the triangles' normals point out of it)."""
        local = CELL_TRIANGLES[self.cells.boundary_triangle[index]]
        cell = self.cells.boundary_cell[index]
        a, b, c = (self.cells.corners[cell, local[:, k]] for k in range(3))
        exact, u, v, usable, outward = ray_triangle(self.origins[rays], self.directions[rays],
                                                    a, b, c)
        close = usable & (np.abs(exact - t) < 1e-3 * (1 + np.abs(t)))
        return np.where(close, exact, t), u, v, outward

    def _start_inside(self, rays):
        """Rays whose first boundary crossing leaves the occupied set start inside it: they
        are walked from where the backward ray leaves it, and clipped at the origin.
        Returns (index, t, u, v) of that backward crossing (t < 0); index -1 if none."""
        back_index, back_t = self.caster.cast(self.origins[rays], -self.directions[rays],
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
        """One step for every walker: find its exit, record the segment, move on."""
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
        # A lost walker (no exit found) re-seeks beyond every crossing of its cell: a ray
        # can leave through the other triangle of a folded entry face, and re-seeking from
        # just past its entry would find that entry again through float32 caster error.
        far_side = np.where(hit & (t > t_in[:, None]), t, -np.inf).max(1)
        # An exit crosses a face outward: at a corner or edge this picks, among the faces
        # touched there, one that leads on rather than back.
        hit &= outward & ((np.arange(12) // 2)[None] != entry_face[:, None])
        ahead = hit & (t > t_in[:, None] + self.step)
        touching = hit & (t >= t_in[:, None] - self.step)
        has_ahead = ahead.any(1)
        exit_triangle = np.where(has_ahead, np.where(ahead, t, np.inf).argmin(1),
                                 np.where(touching, t, -np.inf).argmax(1))
        lost = ~touching.any(1)
        rows = np.arange(len(ray))
        t_out = np.maximum(t[rows, exit_triangle], t_in)
        p_out = self.cells.rest_point(cell, exit_triangle, u[rows, exit_triangle],
                                      v[rows, exit_triangle])
        beyond = t_out <= self.far[ray]
        record = has_ahead & beyond
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
        """All Segments walked so far, ordered by ray then distance."""
        return _segments(self.pieces, truncated=self.active())


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
