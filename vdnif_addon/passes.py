"""The per-ray answers every renderer writes, reference or network: one record per ray (per
pixel) of hit, distance, normal, albedo and material. The tracing, the kernels and the
inference all read and write it, so it sits below them all."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int


@dataclass
class Passes:
    """Per-ray (per-pixel) results: what a reference or the network says each ray sees."""

    hit: Bool[np.ndarray, " R"]
    distance: Float[np.ndarray, " R"]     # float64 along the deformed ray, object-local units
    normal: Float[np.ndarray, "R 3"]     # float64 unit, deformed space
    albedo: Float[np.ndarray, "R 3"]     # float32
    material: Int[np.ndarray, " R"]       # int32: index into the mesh's used materials
    cell: Int[np.ndarray, " R"] | None = None
    """int32: the occupied cell the network placed the hit in, -1 for a miss; None from a
    renderer that walks no cells (the references)."""

    @classmethod
    def empty(cls, rays: int) -> Passes:
        """Passes of ``rays`` rays that hit nothing (every pass zero)."""
        return cls(hit=np.zeros(rays, bool), distance=np.zeros(rays),
                   normal=np.zeros((rays, 3)), albedo=np.zeros((rays, 3), np.float32),
                   material=np.zeros(rays, np.int32))

    @classmethod
    def concatenate(cls, passes: Iterable[Passes]) -> Passes:
        """The rays of ``passes`` one after the other (their cells where every one has
        them)."""
        passes = list(passes)
        cells = [p.cell for p in passes]
        return cls(*(np.concatenate([getattr(p, name) for p in passes])
                     for name in ("hit", "distance", "normal", "albedo", "material")),
                   cell=None if any(c is None for c in cells) else np.concatenate(cells))

    def with_slots(self, slots: Int[np.ndarray, " K"]) -> Passes:
        """A copy whose material pass holds the Blender material slot the user knows:
        ``slots`` (K,) maps the used-material index to its slot (RestMesh.material_slots);
        0 where nothing is hit."""
        slots = np.asarray(slots, np.int32)
        material = np.where(self.hit, slots[np.clip(self.material, 0, len(slots) - 1)], 0)
        return Passes(hit=self.hit, distance=self.distance, normal=self.normal,
                      albedo=self.albedo, material=material.astype(np.int32), cell=self.cell)


COMPOSITOR_PASSES = {"Combined": "RGBA", "Depth": "Z", "Normal": "XYZ", "DiffCol": "RGB",
                     "IndexMA": "X"}
"""The passes of the multilayer EXR, by the names Cycles gives them in a render result, and
their channels: Combined is the albedo with the hit mask as alpha (there is no lighting),
Depth the distance along the ray, Normal in world space where the view is in world space,
DiffCol the albedo, IndexMA the material slot."""
COMPOSITOR_SOURCES = {"Depth": "distance", "Normal": "normal", "DiffCol": "albedo",
                      "IndexMA": "material"}
"""The field of Passes each compositor pass holds (Combined: albedo and hit)."""
VIEW_LAYER = "ViewLayer"
"""The layer name of the EXR's passes: Blender's default view layer's."""
MISS_DEPTH = 1e10
"""Depth where a ray hits nothing: the far value Cycles writes for the background."""


SECONDARY_PASSES = ("ao", "shadow")
"""The passes of the rays that start at each primary hit (``inference/secondary.py``):
ambient occlusion, the fraction of cosine-weighted rays with no occluder within the AO
distance (1 open, 0 enclosed), and shadow, whether the light is reached (1 lit, 0 shadowed)."""
SECONDARY_COMPOSITOR = {"AO": "ao", "Shadow": "shadow"}
"""The secondary passes in the multilayer EXR, by the names Blender's render passes give them
(Cycles' AO, EEVEE's Shadow), each RGB grey: 0 where nothing is hit."""
SHADED_PASS = "shaded"
"""The shaded image (``inference/shading.py``): the albedo under the scene's light and world,
made of the primary passes and of both secondary ones, AO and shadow."""
SHADED_COMPOSITOR = {"Shaded": "RGB"}
"""The shaded pass in the multilayer EXR: linear RGB (the world's colour where nothing is
hit), its own name: Combined holds the albedo."""
TOGGLED_PASSES = (*SECONDARY_PASSES, SHADED_PASS)
"""The passes that cost rays beyond the primary ones, each behind its own toggle."""
PASS_NEEDS = {SHADED_PASS: SECONDARY_PASSES}
"""The passes a toggled pass is computed from: a toggled Shaded casts the AO and shadow rays
whether or not their own toggles are on (those toggles say only what is written)."""


def cast_passes(names: Iterable[str]) -> tuple[str, ...]:
    """The secondary passes whose rays the toggled passes ``names`` need (``PASS_NEEDS``):
    the toggled ones and the ones a toggled pass is computed from."""
    names = set(names)
    needed = names | {need for name in names for need in PASS_NEEDS.get(name, ())}
    return tuple(name for name in SECONDARY_PASSES if name in needed)


@dataclass
class SecondaryPasses:
    """Per-ray (per-pixel) answers of the secondary rays of one set of primary hits."""

    hit: Bool[np.ndarray, " R"]       # the primary hit the secondary rays start from
    ao: Float[np.ndarray, " R"]       # float32 fraction unoccluded; 0 without a primary hit
    lit: Bool[np.ndarray, " R"]       # the light reached; False without a primary hit
    # the hit's normal faces the light (no shadow ray is cast from one that does not);
    # False without a primary hit
    facing: Bool[np.ndarray, " R"]

    @classmethod
    def concatenate(cls, passes: Iterable[SecondaryPasses]) -> SecondaryPasses:
        """The rays of ``passes`` one after the other."""
        passes = list(passes)
        return cls(*(np.concatenate([getattr(p, name) for p in passes])
                     for name in ("hit", "ao", "lit", "facing")))
