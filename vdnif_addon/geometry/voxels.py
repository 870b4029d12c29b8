"""Sparse voxel grid of the rest mesh, and the inversion test for deformed cells.

The grid is the embedding that the network lives in (design sections 2-4): cubic cells of edge
``h = longest rest AABB extent / R``; a cell is occupied iff a triangle overlaps its closed box
(exact separating-axis test, so thin parts are never missed). Occupied cells are stored
sparsely with a face-neighbour table for the traversal and the unique corner lattice points
that the deformation moves.

Cell ``(i, j, k)`` spans ``origin + [i, i+1] x [j, j+1] x [k, k+1] * h``; its linear index is
``i + dims[0] * (j + dims[1] * k)``. ``GridRecord`` is the grid as dataset headers and model
files record it, checked by one set of rules. Pure numpy: never imports bpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from ..errors import VDNIFError
from ..safe_io import finite_number, shown
from ..settings import MAX_RESOLUTION, MIN_RESOLUTION

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

# Cell boxes are closed and grown by this fraction of a voxel on every side, so a triangle that
# lies in a cell face or touches a cell edge or corner (up to rounding) overlaps every cell
# sharing that face, edge or corner. Relative to h, so it does not depend on the mesh's scale.
BOX_TOLERANCE = 1e-6

# Candidate (triangle, cell) pairs put through the separating-axis test at once: bounds the
# test's working memory (about 1 KB per pair) whatever the mesh size and resolution.
PAIRS_PER_CHUNK = 1 << 14

# Candidate ranges are grown by more than the boxes, so rounding never drops a cell the test
# would accept; extra candidates only cost a test.
CANDIDATE_MARGIN = 2 * BOX_TOLERANCE

# (8, 3) offset (dx, dy, dz) of corner number c = dx + 2*dy + 4*dz.
CORNER_OFFSETS = (np.arange(8)[:, None] >> np.arange(3)) & 1

# (6, 3) offset of the face neighbours, in the order -x, +x, -y, +y, -z, +z.
NEIGHBOUR_OFFSETS = np.array(
    [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], dtype=np.int64
)

# (8, 3) corner numbers at the low and high end of the cell edge along each axis through each
# corner: the trilinear map's Jacobian at corner c has columns X[_EDGE_HIGH[c]] - X[_EDGE_LOW[c]].
_AXIS_BITS = 1 << np.arange(3)
_EDGE_LOW = np.arange(8)[:, None] & ~_AXIS_BITS
_EDGE_HIGH = np.arange(8)[:, None] | _AXIS_BITS

# (3, 3, 3) cross-product matrices of the box axes, for row vectors: f @ M[k] = e_k x f.
_BOX_AXIS_CROSS = np.cross(np.eye(3)[:, None, :], np.eye(3)[None, :, :])


GRID_KEYS = ("origin", "voxel_size", "dims", "resolution", "extent")
"""What places a voxel grid in rest space, as dataset headers and model files store it."""
_GRID_EXTRAS = ("occupied_voxels", "mesh_fingerprint")
_TEXTURES = "texture_fingerprint"       # written only where known: older files lack it
_MAX_DIMS = 2**31 - 1            # cells per axis that an int32 cell index can count


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and finite_number(value)


@dataclass(frozen=True)
class GridRecord:
    """A voxel grid as dataset headers and model files record it: origin and voxel size in
    rest units, dims, the resolution asked for, the extent (voxel size times the longest
    dims); the occupied voxel count and the rest mesh's fingerprint
    (``model_file.mesh_fingerprint``) where the writer knew them, and its textures'
    (``model_file.texture_fingerprint``; files written before it lack it). ``VoxelGrid.record``
    makes one, ``from_dict`` reads one; both check it with the same rules, so a record in
    hand is valid."""

    origin: tuple[float, float, float]
    voxel_size: float
    dims: tuple[int, int, int]
    resolution: int
    extent: float
    occupied_voxels: int | None = None
    mesh_fingerprint: str | None = None
    texture_fingerprint: str | None = None

    def __post_init__(self) -> None:
        if (problem := grid_problem(self.to_dict())) is not None:
            raise VDNIFError(problem)
        # Sequences in, tuples kept: equal records compare equal whatever made them.
        object.__setattr__(self, "origin", tuple(map(float, self.origin)))
        object.__setattr__(self, "dims", tuple(map(int, self.dims)))

    def placement(self) -> tuple[Any, ...]:
        """The ``GRID_KEYS`` values: equal for every shard of one dataset folder."""
        return tuple(getattr(self, key) for key in GRID_KEYS)

    def to_dict(self, *, with_none: bool = False) -> dict[str, Any]:
        """Plain data: the ``GRID_KEYS`` entries, then the occupied voxels and the mesh
        fingerprint where known (``with_none``: always, null where unknown, as model files
        store them)."""
        data = {"origin": list(self.origin), "voxel_size": self.voxel_size,
                "dims": list(self.dims), "resolution": self.resolution, "extent": self.extent}
        for key in _GRID_EXTRAS:
            if with_none or getattr(self, key) is not None:
                data[key] = getattr(self, key)
        if self.texture_fingerprint is not None:
            data[_TEXTURES] = self.texture_fingerprint
        return data

    @classmethod
    def from_dict(cls, data: object, fail: Callable[[str], NoReturn]) -> GridRecord:
        """The grid entry ``data`` (plain data) of a file, checked; ``fail`` turns a problem
        into the file's one-line error and raises it."""
        if (problem := grid_problem(data)) is not None:
            fail(problem)
        return cls(origin=data["origin"], voxel_size=float(data["voxel_size"]), dims=data["dims"],
                   resolution=int(data["resolution"]), extent=float(data["extent"]),
                   occupied_voxels=data.get("occupied_voxels"),
                   mesh_fingerprint=data.get("mesh_fingerprint"),
                   texture_fingerprint=data.get(_TEXTURES))


def grid_problem(data: object) -> str | None:
    """Why ``data`` is not a grid entry (``GridRecord.to_dict``'s shape), or None: the
    grid's one set of rules, for dataset headers, manifests and model files alike."""
    if not isinstance(data, Mapping) or any(key not in data for key in GRID_KEYS):
        return f"has no complete grid ({', '.join(GRID_KEYS)})"
    if unknown := sorted(set(data) - {*GRID_KEYS, *_GRID_EXTRAS, _TEXTURES}):
        return f"grid has unknown entries {', '.join(map(shown, unknown))}"
    origin, dims = data["origin"], data["dims"]
    if not (isinstance(origin, (list, tuple)) and len(origin) == 3
            and all(map(_is_number, origin))):
        return f"grid origin {shown(origin)} is not 3 numbers"
    if not (isinstance(dims, (list, tuple)) and len(dims) == 3
            and all(_is_int(n) and 1 <= n <= _MAX_DIMS for n in dims)):
        return f"grid dims {shown(dims)} are not 3 counts"
    h, extent = data["voxel_size"], data["extent"]
    if not (_is_number(h) and h > 0 and _is_number(extent) and extent > 0):
        return "grid voxel size or extent is not a positive number"
    if abs(extent - h * max(dims)) > 1e-6 * extent:
        return (f"grid extent {shown(extent)} is not its voxel size {shown(h)} times its "
                f"longest dims {max(dims)}")
    if (problem := resolution_problem(data["resolution"])) is not None:
        return f"grid {problem}"
    occupied = data.get("occupied_voxels")
    if occupied is not None and not (_is_int(occupied) and 0 <= occupied <= math.prod(dims)):
        return f"grid occupied_voxels {shown(occupied)} is not an integer 0..{math.prod(dims)}"
    for key in ("mesh_fingerprint", _TEXTURES):
        fingerprint = data.get(key)
        if fingerprint is not None and (not isinstance(fingerprint, str) or not fingerprint):
            return f"grid {key} {shown(fingerprint)} is not a string"
    return None


@dataclass(frozen=True, eq=False)
class VoxelGrid:
    """The occupied cells of a padded rest-space grid, stored sparsely.

    ``eq=False``: fields are arrays, so instances compare and hash by identity.
    """

    origin: Float[np.ndarray, "3"]  # float64: the grid's min corner
    voxel_size: float  # h
    dims: Int[np.ndarray, "3"]  # int64: cells per axis
    resolution: int  # R, as requested: dims.max() == R + 2
    cells: Int[np.ndarray, "N 3"]  # int32: ijk of occupied cells, sorted by linear index
    neighbours: Int[np.ndarray, "N 6"]  # int32: index of the -x,+x,-y,+y,-z,+z neighbour, or -1
    corners: Int[np.ndarray, "C 3"]  # int32: ijk of the unique lattice points of occupied cells
    cell_corners: Int[np.ndarray, "N 8"]  # int32: index into corners, corner c = dx + 2dy + 4dz

    @property
    def extent(self) -> float:
        """Edge of the cube that encloses the whole padded grid: ``h * dims.max()``."""
        return self.voxel_size * float(self.dims.max())

    def corner_positions(self) -> Float[np.ndarray, "C 3"]:
        """(C, 3) float64 rest-space positions of ``corners``."""
        return self.origin + self.corners * self.voxel_size

    def normalize(self, points: Float[np.ndarray, "*batch 3"]) -> Float[np.ndarray, "*batch 3"]:
        """(..., 3) float64: rest-space ``points`` (..., 3) mapped so the grid fits in [0,1]^3.

        One scale for all axes, so the encoder sees undistorted shapes. The scale is the padded
        grid's ``h * dims.max()`` rather than the design's ``h * R``, so the margin cells map
        into [0, 1] too.
        """
        return (np.asarray(points, dtype=np.float64) - self.origin) / self.extent

    def record(self, mesh_fingerprint: str | None = None,
               texture_fingerprint: str | None = None) -> GridRecord:
        """The grid as files record it, with its occupied voxel count and, where given, the
        fingerprints of the rest mesh voxelized and of its textures."""
        return GridRecord(origin=tuple(self.origin.tolist()), voxel_size=float(self.voxel_size),
                          dims=tuple(self.dims.tolist()), resolution=int(self.resolution),
                          extent=float(self.extent), occupied_voxels=int(len(self.cells)),
                          mesh_fingerprint=mesh_fingerprint,
                          texture_fingerprint=texture_fingerprint)

    def cell_bounds(self, index: Int[np.ndarray, " N"]
                    ) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, "N 3"]]:
        """Rest-space (lo (N, 3), hi (N, 3)) box corners of the cells ``index`` (N,) int."""
        ijk = self.cells[index]
        return self.origin + ijk * self.voxel_size, self.origin + (ijk + 1) * self.voxel_size


def build_grid(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
               resolution: int) -> VoxelGrid:
    """Voxelizes the mesh ``vertices`` (V, 3) float, ``triangles`` (T, 3) int at ``resolution``.

    ``h = longest AABB extent / resolution``; each axis gets ``floor(extent / h) + 2`` cells and
    the grid is centred on the AABB, so at least h/2 of empty margin surrounds the mesh (exactly
    h on the longest axis, whose ``dims`` is ``resolution + 2``) and a flat object gets few
    layers. Only vertices used by a triangle count for the AABB.
    Raises VDNIFError for an empty, non-finite or zero-size mesh, bad triangle indices or a
    resolution outside 4..256.
    """
    vertices, triangles = _validated_mesh(vertices, triangles)
    resolution = _validated_resolution(resolution)

    used = np.zeros(len(vertices), dtype=bool)
    used[triangles.ravel()] = True
    low, high = vertices[used].min(axis=0), vertices[used].max(axis=0)
    size = high - low
    longest = size.max()
    if longest == 0:
        raise VDNIFError("mesh has zero size: all its vertices are at the same point")
    voxel_size = longest / resolution
    # size / longest is exactly 1 on the longest axis, so its dims is exactly R + 2.
    dims = np.floor(size / longest * resolution).astype(np.int64) + 2
    origin = (low + high) / 2 - dims * voxel_size / 2

    occupied = _occupied_cells(vertices, triangles, origin, voxel_size, dims)
    cells = _unravel(occupied, dims)
    corners, cell_corners = _corner_lattice(cells, dims)
    return VoxelGrid(
        origin=origin,
        voxel_size=float(voxel_size),
        dims=dims,
        resolution=resolution,
        cells=cells.astype(np.int32),
        neighbours=_neighbour_table(cells, occupied, dims),
        corners=corners,
        cell_corners=cell_corners,
    )


def cell_jacobian_determinants(corner_positions: Float[np.ndarray, "C 3"],
                               cell_corners: Int[np.ndarray, "N 8"]
                               ) -> Float[np.ndarray, "N 8"]:
    """(N, 8) float64 determinant of each cell's trilinear map at each of its corners.

    ``corner_positions`` (C, 3) are (deformed) corner positions, ``cell_corners`` (N, 8) index
    them. At a corner the Jacobian's columns are the cell edges through it, each oriented
    toward +x, +y, +z, so an undeformed cube of edge h gives h^3 everywhere. Non-finite
    corners give non-finite determinants, silently.
    """
    points = np.asarray(corner_positions, dtype=np.float64)[np.asarray(cell_corners)]
    with np.errstate(invalid="ignore", over="ignore"):
        edges = points[:, _EDGE_HIGH] - points[:, _EDGE_LOW]  # (N, 8, axis, xyz)
        return np.sum(edges[:, :, 0] * np.cross(edges[:, :, 1], edges[:, :, 2]), axis=-1)


def inverted_cells(corner_positions: Float[np.ndarray, "C 3"],
                   cell_corners: Int[np.ndarray, "N 8"]) -> Bool[np.ndarray, " N"]:
    """(N,) bool: cells whose determinant is not positive at some corner, or not finite.

    A cell with a NaN or infinite corner counts as inverted: it cannot be traversed.
    """
    corner_positions = np.asarray(corner_positions, dtype=np.float64)
    cell_corners = np.asarray(cell_corners)
    finite = np.isfinite(corner_positions)[cell_corners].all(axis=(1, 2))
    positive = (cell_jacobian_determinants(corner_positions, cell_corners) > 0).all(axis=1)
    return ~(finite & positive)


def _validated_mesh(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"]
                    ) -> tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "T 3"]]:
    """(V, 3) float64 vertices and (T, 3) int64 triangles, or VDNIFError saying what is wrong."""
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles)
    if vertices.size == 0:
        raise VDNIFError("mesh has no vertices")
    if triangles.size == 0:
        raise VDNIFError("mesh has no triangles")
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise VDNIFError(f"mesh vertices have shape {vertices.shape}, expected (V, 3)")
    if triangles.ndim != 2 or triangles.shape[1] != 3:
        raise VDNIFError(f"mesh triangles have shape {triangles.shape}, expected (T, 3)")
    if triangles.dtype.kind not in "iu":
        raise VDNIFError(f"mesh triangle indices must be integers, not {triangles.dtype}")
    if not np.isfinite(vertices).all():
        raise VDNIFError("mesh has non-finite vertex coordinates (NaN or infinity)")
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        bad = triangles.min() if triangles.min() < 0 else triangles.max()
        raise VDNIFError(
            f"mesh has triangle vertex index {bad} out of range for {len(vertices)} vertices"
        )
    return vertices, triangles.astype(np.int64)


def resolution_problem(resolution: object) -> str | None:
    """Why ``resolution`` is not a voxel resolution (an integer in ``MIN_RESOLUTION`` ..
    ``MAX_RESOLUTION``, declared in ``settings``), or None: the one check of the range, for
    a grid built and a grid read alike."""
    allowed = f"{MIN_RESOLUTION}..{MAX_RESOLUTION}"
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        return f"resolution {shown(resolution)} is not an integer in {allowed}"
    if not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        return f"resolution {resolution} is outside the allowed range {allowed}"
    return None


def _validated_resolution(resolution: object) -> int:
    """``resolution`` as an int, or VDNIFError naming it and the allowed range."""
    if (problem := resolution_problem(resolution)) is not None:
        raise VDNIFError(f"voxel {problem}")
    return int(resolution)


def _occupied_cells(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
                    origin: Float[np.ndarray, "3"], voxel_size: float,
                    dims: Int[np.ndarray, "3"]) -> Int[np.ndarray, " M"]:
    """Sorted unique linear indices (M,) int64 of the cells some triangle overlaps.

    Candidates stay inside the triangle's AABB cell range, which is exactly the separating-axis
    test on the three box normals. Within it the triangle is read as a height field over the
    two axes its normal leans on least: for each column of the AABB along those axes, only the
    cells the triangle's plane can reach there are candidates, so a big slanted triangle costs
    its area in cells, not its AABB volume. The SAT on the remaining ten axes decides each
    candidate, streamed in chunks of at most PAIRS_PER_CHUNK.
    """
    points = (vertices[triangles] - origin) / voxel_size  # (T, 3, 3) in voxel units
    first, last = _cell_range(points.min(axis=1), points.max(axis=1), BOX_TOLERANCE)  # (T, 3)
    # A triangle with a single candidate lies inside that cell's grown box: no test needed.
    single = (first == last).all(axis=1)
    found = [_linear_index(first[single], dims)]

    axis_order, slope, reach_low, reach_high = _height_fields(points)
    first, last = (np.take_along_axis(a, axis_order, axis=1) for a in (first, last))
    span = last - first + 1
    column_counts = np.where(single, 0, span[:, 1] * span[:, 2])
    for triangle, local in _chunked_ranges(column_counts):
        column = first[triangle, 1:] + np.stack(
            [local % span[triangle, 1], local // span[triangle, 1]], axis=1
        )  # (P, 2) cell coordinates along the column axes
        plane_offset = np.einsum("pc,pc->p", slope[triangle], column + 0.5)
        height_first, height_last = _cell_range(
            reach_low[triangle] - plane_offset,
            reach_high[triangle] - plane_offset,
            CANDIDATE_MARGIN,
        )
        height_first = np.maximum(height_first, first[triangle, 0])
        height_last = np.minimum(height_last, last[triangle, 0])
        for pair, step in _chunked_ranges(np.maximum(height_last - height_first + 1, 0)):
            ordered_cell = np.column_stack([height_first[pair] + step, column[pair]])
            cell = np.empty_like(ordered_cell)
            np.put_along_axis(cell, axis_order[triangle[pair]], ordered_cell, axis=1)
            overlaps = _triangle_overlaps_cell(points[triangle[pair]], cell)
            found.append(np.unique(_linear_index(cell[overlaps], dims)))
    return np.unique(np.concatenate(found))


def _cell_range(low: Float[np.ndarray, "*batch"], high: Float[np.ndarray, "*batch"],
                tolerance: float
                ) -> tuple[Int[np.ndarray, "*batch"], Int[np.ndarray, "*batch"]]:
    """First and last int64 cells i whose box [i - tolerance, i+1 + tolerance] meets
    [low, high]."""
    first = np.ceil(low - tolerance).astype(np.int64) - 1
    return first, np.floor(high + tolerance).astype(np.int64)


def _height_fields(points: Float[np.ndarray, "T 3 3"]
                   ) -> tuple[Int[np.ndarray, "T 3"], Float[np.ndarray, "T 2"],
                              Float[np.ndarray, " T"], Float[np.ndarray, " T"]]:
    """Each triangle ``points`` (T, 3, 3) as a height field over two of the axes.

    Returns ``axis_order`` (T, 3) int64: the height axis (the normal's largest component) then
    the two column axes; ``slope`` (T, 2) and ``reach_low``, ``reach_high`` (T,) float64 such
    that over the grown square of the column centred at ``q`` (2,), the triangle's height lies
    in ``[reach_low - slope . q, reach_high - slope . q]``. A zero normal (degenerate triangle)
    gets slope 0, which makes that its whole height range. Any slope is sound: ``height +
    slope . column`` is affine, so over the triangle it stays between its vertex values.
    """
    normal = np.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0])  # (T, 3)
    axis_order = (np.abs(normal).argmax(axis=1)[:, None] + np.arange(3)) % 3
    normal = np.take_along_axis(normal, axis_order, axis=1)
    ordered = np.take_along_axis(points, axis_order[:, None, :], axis=2)  # (T, vertex, axis)
    slope = np.divide(
        normal[:, 1:], normal[:, :1], out=np.zeros((len(normal), 2)), where=normal[:, :1] != 0
    )
    offset = ordered[:, :, 0] + np.einsum("tvc,tc->tv", ordered[:, :, 1:], slope)  # (T, vertex)
    spread = (0.5 + CANDIDATE_MARGIN) * np.abs(slope).sum(axis=1)  # slope . (x - q) in the square
    return axis_order, slope, offset.min(axis=1) - spread, offset.max(axis=1) + spread


def _chunked_ranges(counts: Int[np.ndarray, " K"]
                    ) -> Iterator[tuple[Int[np.ndarray, " P"], Int[np.ndarray, " P"]]]:
    """Yields (owner (P,), local (P,)) int64 enumerating ``local in range(counts[owner])`` for
    every owner of ``counts`` (K,) int64, at most PAIRS_PER_CHUNK pairs at a time."""
    ends = np.cumsum(counts)
    total = int(ends[-1]) if len(ends) else 0
    for start in range(0, total, PAIRS_PER_CHUNK):
        pair = np.arange(start, min(start + PAIRS_PER_CHUNK, total))
        owner = np.searchsorted(ends, pair, side="right")
        yield owner, pair - (ends[owner] - counts[owner])


def _triangle_overlaps_cell(points: Float[np.ndarray, "P 3 3"], cells: Int[np.ndarray, "P 3"]
                            ) -> Bool[np.ndarray, " P"]:
    """(P,) bool: does each triangle ``points`` (P, 3, 3) overlap its cell ``cells`` (P, 3)?

    Both in voxel units; the box is the cell grown by BOX_TOLERANCE. Separating-axis test
    (Akenine-Moller) on the triangle normal and the 9 box-axis x edge cross products; the box
    normals were settled by the candidate range (the height-field candidates only approximate
    the normal's test, from outside). Axes are not normalized: a zero axis (the
    normal of a triangle collapsed to a segment, every axis of one collapsed to a point) gives
    zero projections and zero radius, never separates and never makes NaN, and what remains is
    the exact test for the segment or point.
    """
    relative = points - (cells + 0.5)[:, None, :]  # vertices relative to the box centre
    edges = np.roll(relative, -1, axis=1) - relative  # (P, 3, 3): v1-v0, v2-v1, v0-v2
    normal = np.cross(edges[:, 0], edges[:, 1])
    edge_axes = edges[:, None] @ _BOX_AXIS_CROSS  # (P, box axis, edge, 3): e_k x edge
    axes = np.concatenate([normal[:, None], edge_axes.reshape(-1, 9, 3)], axis=1)  # (P, 10, 3)
    projections = axes @ relative.transpose(0, 2, 1)  # (P, 10, vertex)
    low = np.minimum(projections[..., 0], np.minimum(projections[..., 1], projections[..., 2]))
    high = np.maximum(projections[..., 0], np.maximum(projections[..., 1], projections[..., 2]))
    radius = np.abs(axes) @ np.full(3, 0.5 + BOX_TOLERANCE)  # (P, 10) box half-width on each axis
    return ~((low > radius) | (high < -radius)).any(axis=1)


def _linear_index(ijk: Int[np.ndarray, "*batch 3"], dims: Int[np.ndarray, "3"]
                  ) -> Int[np.ndarray, "*batch"]:
    """(...,) int64 linear index ``i + dims[0] * (j + dims[1] * k)`` of ``ijk`` (..., 3)."""
    ijk = np.asarray(ijk, dtype=np.int64)
    return ijk[..., 0] + dims[0] * (ijk[..., 1] + dims[1] * ijk[..., 2])


def _unravel(linear: Int[np.ndarray, " M"], dims: Int[np.ndarray, "3"]) -> Int[np.ndarray, "M 3"]:
    """(M, 3) int64 ijk of the linear indices ``linear`` (M,)."""
    return np.stack(np.unravel_index(linear, tuple(dims), order="F"), axis=1).astype(np.int64)


def _neighbour_table(cells: Int[np.ndarray, "N 3"], linear: Int[np.ndarray, " N"],
                     dims: Int[np.ndarray, "3"]) -> Int[np.ndarray, "N 6"]:
    """(N, 6) int32 index of each cell's face neighbour in ``cells`` (N, 3), or -1 if empty.

    ``linear`` (N,) are the cells' sorted linear indices; neighbours are found by binary search.
    """
    target = cells[:, None, :] + NEIGHBOUR_OFFSETS  # (N, 6, 3)
    inside = ((target >= 0) & (target < dims)).all(axis=2)
    target_linear = _linear_index(target, dims)
    slot = np.minimum(np.searchsorted(linear, target_linear), len(linear) - 1)
    found = inside & (linear[slot] == target_linear)
    return np.where(found, slot, -1).astype(np.int32)


def _corner_lattice(cells: Int[np.ndarray, "N 3"], dims: Int[np.ndarray, "3"]
                    ) -> tuple[Int[np.ndarray, "C 3"], Int[np.ndarray, "N 8"]]:
    """Unique corners (C, 3) int32 of ``cells`` (N, 3) and each cell's corners (N, 8) int32."""
    lattice_dims = dims + 1
    corner_linear = _linear_index(cells[:, None, :] + CORNER_OFFSETS, lattice_dims)  # (N, 8)
    unique, inverse = np.unique(corner_linear.ravel(), return_inverse=True)
    corners = _unravel(unique, lattice_dims).astype(np.int32)
    return corners, inverse.reshape(-1, 8).astype(np.int32)
