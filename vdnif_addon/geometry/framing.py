"""Which part of a mesh frames it: one loose vertex or a stray piece far from the body must
not set the object's size, its voxel grid and every view's framing.

The rule: the main body is the connected piece (triangles sharing vertices) with the most
triangles. Every other piece, and every vertex on no face, is kept when its bounds come within
``FAR_FACTOR`` times the main body's size of the main body's bounds, and left out otherwise
(with a warning that names what was left out). Kept pieces do not widen the reach: the test
is against the main body alone, so a chain of stray pieces cannot walk the bounds away.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

FAR_FACTOR = 1.0
"""How far from the main body's bounds, in its sizes, a piece or vertex still frames the
object: a piece further off is left out of the rest mesh."""


@dataclass(frozen=True)
class Framing:
    """The part of a mesh that frames it: ``vertices`` (V,) and ``triangles`` (T,) bool,
    kept; ``warning``: what was left out, in words (None when nothing was)."""

    vertices: Bool[np.ndarray, " V"]
    triangles: Bool[np.ndarray, " T"]
    warning: str | None

    @property
    def complete(self) -> bool:
        return self.warning is None


def components(vertex_count: int, triangles: Int[np.ndarray, "T 3"]) -> Int[np.ndarray, " V"]:
    """(V,) the connected piece of each vertex: the smallest vertex index of its piece
    (triangles that share a vertex are one piece; a vertex on no face is a piece of its
    own)."""
    label = np.arange(vertex_count)
    corners = np.asarray(triangles, np.int64).ravel()
    if corners.size == 0:
        return label
    while True:
        lowest = label[np.asarray(triangles, np.int64)].min(axis=1)
        joined = label.copy()
        np.minimum.at(joined, corners, np.repeat(lowest, 3))
        np.minimum.at(joined, label, joined)          # hook each old root to its lowest
        while True:                                    # pointer jumping to the roots
            jumped = joined[joined]
            if np.array_equal(jumped, joined):
                break
            joined = jumped
        if np.array_equal(joined, label):
            return label
        label = joined


def framing(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
            name: str = "the mesh") -> Framing:
    """The part of the mesh ``vertices`` / ``triangles`` that frames it (module docstring);
    ``name`` names the object in the warning."""
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles, np.int64)
    label = components(len(vertices), triangles)
    roots, piece = np.unique(label, return_inverse=True)
    piece_triangles = np.bincount(piece[triangles[:, 0]], minlength=len(roots)) \
        if len(triangles) else np.zeros(len(roots), np.int64)
    main = int(np.argmax(piece_triangles))
    lo = np.full((len(roots), 3), np.inf)
    hi = np.full((len(roots), 3), -np.inf)
    np.minimum.at(lo, piece, vertices)
    np.maximum.at(hi, piece, vertices)
    reach = FAR_FACTOR * float(np.ptp(np.stack([lo[main], hi[main]]), axis=0).max())
    near = np.all((lo <= hi[main] + reach) & (hi >= lo[main] - reach), axis=1)
    kept_vertices = near[piece]
    kept_triangles = kept_vertices[triangles[:, 0]] if len(triangles) else np.zeros(0, bool)
    if kept_vertices.all():
        return Framing(kept_vertices, kept_triangles, None)
    far = ~near
    loose = far & (piece_triangles == 0)
    parts = []
    if loose.any():
        parts.append(_count(int(loose.sum()), "loose vertex", "loose vertices"))
    if (far & ~loose).any():
        parts.append(f"{_count(int((far & ~loose).sum()), 'piece', 'pieces')} of "
                     f"{_count(int((~kept_triangles).sum()), 'triangle', 'triangles')}")
    warning = (f"'{name}': left out {' and '.join(parts)} more than {FAR_FACTOR:g} x the "
               f"main body's size ({reach / FAR_FACTOR:.4g}) away from it: they would set "
               "the object's size and framing; they are not trained or rendered")
    return Framing(kept_vertices, kept_triangles, warning)


def _count(number: int, one: str, many: str) -> str:
    return f"{number} {one if number == 1 else many}"


def framing_bounds(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"]
                   ) -> tuple[Float[np.ndarray, "3"], Float[np.ndarray, "3"]]:
    """(lo, hi) the bounds of the part that frames the mesh (``framing``)."""
    kept = np.asarray(vertices, np.float64)[framing(vertices, triangles).vertices]
    return kept.min(axis=0), kept.max(axis=0)
