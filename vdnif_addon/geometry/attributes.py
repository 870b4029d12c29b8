"""Surface attributes at hit points: albedo and material, and the trilinear cell map whose
Jacobian carries rest normals into deformed space. (Barycentric weights and shading normals of
hits are computed where the hits are found, in ``kernels.surface``.)

Pure numpy, vectorized over all points (DESIGN sections 6 and 7). Degenerate input (zero-area
triangles, singular Jacobians, zero vectors) gives documented finite fallbacks, never NaN.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import VDNIFError
from .restmesh import TEXTURE_EXTENSIONS, RestMesh

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

    from .restmesh import Albedo

# A triangle is treated as degenerate (a segment or a point) when sin^2 of its angle at
# corner 0 is below this: the plane solve would then amplify rounding noise.
DEGENERATE_SIN2 = 1e-12

# Cofactor normals shorter than this, after J is scaled to unit max entry, are rounding noise
# of a rank <= 1 Jacobian (its cofactor is exactly 0); the rest normal is kept then.
SINGULAR_COFACTOR = 1e-12

# Returned where no normal can be defined (zero interpolated normal on a zero-area triangle).
FALLBACK_NORMAL = np.array([0.0, 0.0, 1.0])


def normalize(vectors: Float[np.ndarray, "N 3"],
              fallback: Float[np.ndarray, "3"] | Float[np.ndarray, "N 3"]
              ) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit vectors; rows of zero (or non-finite) length become ``fallback`` (3,) or
    (N, 3), so the result never holds NaN."""
    vectors = np.asarray(vectors, dtype=np.float64)
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    ok = np.isfinite(length) & (length > 0)
    unit = vectors / np.where(ok, length, 1.0)
    return np.where(ok, unit, np.broadcast_to(fallback, vectors.shape))


def has_area(corners: Float[np.ndarray, "T 3 3"]) -> Bool[np.ndarray, " T"]:
    """(T,) bool: triangles with corners (T, 3, 3) that are not degenerate, i.e. sin^2 of
    the angle at corner 0 is at least DEGENERATE_SIN2 (|e1 x e2|^2 = d11 d22 - d12^2)."""
    corners = np.asarray(corners, dtype=np.float64)
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    d11, d12, d22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    return d11 * d22 - d12 * d12 > DEGENERATE_SIN2 * d11 * d22


def interpolate(values: Float[np.ndarray, "N 3 K"], weights: Float[np.ndarray, "N 3"]
                ) -> Float[np.ndarray, "N K"]:
    """(N, K): per-corner values (N, 3, K) blended with barycentric weights (N, 3)."""
    return np.einsum("nck,nc->nk", values, weights)


def sample_texture(texture: Float[np.ndarray, "H W C"], uv: Float[np.ndarray, "N 2"],
                   extension: str) -> Float[np.ndarray, "N C"]:
    """(N, C) float32 bilinear lookup of ``texture`` (H, W, C), row 0 at v = 0, at uv (N, 2).

    Matches Cycles' Image Texture node with Linear interpolation (kernel ``interp_linear``):
    texel (i, j) is centred at ((i + 0.5) / W, (j + 0.5) / H); the four texels around
    (u W - 0.5, v H - 0.5) are blended, with indices out of range resolved per extension:
    REPEAT wraps, EXTEND clamps to the edge texel, MIRROR reflects (period 2W, edge texels
    repeated), CLIP reads them as black. Like Cycles (and EEVEE's ``tex_clip_linear``), CLIP
    therefore fades to black over the half texel just outside [0, 1] and is exactly black
    beyond it; it is not cut off sharply at the unit square. Computed in float64 where
    Blender uses float32.
    """
    texture = np.asarray(texture)
    if texture.ndim != 3 or texture.shape[0] == 0 or texture.shape[1] == 0:
        raise VDNIFError(f"texture must be an (H, W, C) image, got shape {texture.shape}")
    if extension not in TEXTURE_EXTENSIONS:
        raise VDNIFError(f"unknown texture extension {extension!r}, "
                         f"expected one of {', '.join(TEXTURE_EXTENSIONS)}")
    height, width = texture.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    x, x_weight = _texel_pairs(uv[:, 0], width, extension)
    y, y_weight = _texel_pairs(uv[:, 1], height, extension)
    footprint = texture[y[:, :, None], x[:, None, :]]                  # (N, 2, 2, C)
    blend = y_weight[:, :, None] * x_weight[:, None, :]                 # (N, 2, 2)
    return np.einsum("nab,nabc->nc", blend, footprint).astype(np.float32)


def _texel_pairs(coordinate: Float[np.ndarray, " N"], size: int, extension: str
                 ) -> tuple[Int[np.ndarray, "N 2"], Float[np.ndarray, "N 2"]]:
    """Indices (N, 2) of the two texels around each coordinate (N,) along one axis, resolved
    per extension mode, and their linear weights (N, 2); CLIP weights texels outside the
    image by 0 (their index is clamped only to stay valid)."""
    position = coordinate * size - 0.5
    low = np.floor(position)
    fraction = (position - low)[:, None]
    index = low.astype(np.int64)[:, None] + np.array([0, 1])
    weight = np.concatenate([1.0 - fraction, fraction], axis=1)
    if extension == "REPEAT":
        return index % size, weight
    if extension == "MIRROR":
        index = index % (2 * size)
        return np.where(index >= size, 2 * size - 1 - index, index), weight
    if extension == "CLIP":
        weight = np.where((index >= 0) & (index < size), weight, 0.0)
    return np.clip(index, 0, size - 1), weight


def surface_albedo(mesh: RestMesh, triangle: Int[np.ndarray, " N"],
                   weights: Float[np.ndarray, "N 3"]
                   ) -> tuple[Float[np.ndarray, "N 3"], Int[np.ndarray, " N"]]:
    """Albedo (N, 3) float32 and material slot (N,) int32 of surface points given by
    triangle (N,) int and barycentric weights (N, 3), from the triangle's material (DESIGN
    section 7: constant; texture at the interpolated UV; interpolated color attribute; a
    texture without UVs or an attribute without colors falls back to the constant color).
    Shading normals are read in the hit kernel (``kernels.surface``)."""
    triangle = np.asarray(triangle, dtype=np.int64)
    weights = np.asarray(weights, dtype=np.float64)
    material = np.asarray(mesh.material_index, dtype=np.int32)[triangle]
    if len(material) and (material.min() < 0 or material.max() >= mesh.material_count):
        raise VDNIFError(f"mesh {mesh.name!r}: material index out of range of its "
                         f"{mesh.material_count} material slot(s)")
    albedo = np.zeros((len(triangle), 3), dtype=np.float32)
    if mesh.material_count == 1:
        # One slot (the common case): no per-slot masks over every hit.
        albedo[:] = _albedo(mesh, mesh.albedo[0], triangle, weights)
        return albedo, material
    for slot in np.unique(material):
        mask = material == slot
        albedo[mask] = _albedo(mesh, mesh.albedo[slot], triangle[mask], weights[mask])
    return albedo, material


def _albedo(mesh: RestMesh, source: Albedo, triangle: Int[np.ndarray, " n"],
            weights: Float[np.ndarray, "n 3"]
            ) -> Float[np.ndarray, "n 3"] | Float[np.ndarray, "3"]:
    """(n, 3) albedo of points on triangles of one material ``source`` (an Albedo)."""
    if source.kind == "texture" and mesh.uvs is not None and source.texture is not None:
        uv = interpolate(np.asarray(mesh.uvs, dtype=np.float64)[triangle], weights)
        return sample_texture(source.texture, uv, source.extension)
    if source.kind == "attribute" and mesh.corner_colors is not None:
        return interpolate(np.asarray(mesh.corner_colors, dtype=np.float64)[triangle], weights)
    return source.color


def sample_surface(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
                   count: int, rng: np.random.Generator
                   ) -> tuple[Float[np.ndarray, "count 3"], Int[np.ndarray, " count"],
                              Float[np.ndarray, "count 3"]]:
    """Area-weighted uniform samples on a triangle mesh.

    Returns points (count, 3) float64, triangle (count,) intp and barycentric weights
    (count, 3). Zero-area triangles have probability 0; a mesh of zero total area raises
    VDNIFError.
    """
    if count < 0:
        raise VDNIFError(f"sample count must be >= 0, got {count}")
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles)]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                          corners[:, 2] - corners[:, 0]), axis=1)
    total = areas.sum()
    if not (np.isfinite(total) and total > 0):
        raise VDNIFError("cannot sample the surface: the mesh has zero (or invalid) area")
    triangle = rng.choice(len(areas), size=count, p=areas / total)
    root = np.sqrt(rng.random(count))
    second = rng.random(count)
    weights = np.stack([1.0 - root, root * (1.0 - second), root * second], axis=1)
    return interpolate(corners[triangle], weights), triangle, weights


def _dot(a: Float[np.ndarray, "*batch 3"], b: Float[np.ndarray, "*batch 3"]
         ) -> Float[np.ndarray, "*batch"]:
    """Row-wise dot product over the last axis."""
    return np.einsum("...i,...i->...", a, b)
