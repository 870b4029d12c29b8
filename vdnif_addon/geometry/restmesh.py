"""The rest mesh: triangles in the object's local rest space with everything the ground
truth needs (shading normals, UVs, colors, material slots and their albedo sources)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

ALBEDO_KINDS = ("constant", "texture", "attribute")
TEXTURE_EXTENSIONS = ("REPEAT", "EXTEND", "CLIP", "MIRROR")


@dataclass
class Albedo:
    """Where a material's albedo comes from (Principled Base Color, linear RGB)."""

    kind: str
    color: Float[np.ndarray, "3"]        # float32: the constant, or the fallback
    texture: Float[np.ndarray, "H W 3"] | None = None  # float32 linear, row 0 at v = 0
    extension: str = "REPEAT"            # the Image Texture node's extension mode
    source: str = ""                     # material / image / attribute name, for messages

    def __post_init__(self) -> None:
        assert self.kind in ALBEDO_KINDS and self.extension in TEXTURE_EXTENSIONS


@dataclass
class RestMesh:
    """A triangulated mesh in local rest space (every deform modifier disabled)."""

    name: str
    vertices: Float[np.ndarray, "V 3"]            # float64
    triangles: Int[np.ndarray, "T 3"]             # int32
    corner_normals: Float[np.ndarray, "T 3 3"]    # float32 shading normal per corner
    material_index: Int[np.ndarray, " T"]          # int32 index into ``albedo`` per triangle
    albedo: list[Albedo] = field(default_factory=list)  # one per used material (>= 1)
    uvs: Float[np.ndarray, "T 3 2"] | None = None            # float32
    corner_colors: Float[np.ndarray, "T 3 3"] | None = None  # float32 linear
    triangle_loops: Int[np.ndarray, "T 3"] | None = None     # int64 face-corner of each corner
    warnings: list[str] = field(default_factory=list)
    used_slots: Int[np.ndarray, " K"] | None = None  # int32, see ``material_slots``
    # Blender's vertices that are these, where far pieces were left out (geometry.framing)
    source_vertices: Bool[np.ndarray, " S"] | None = None

    @property
    def material_slots(self) -> Int[np.ndarray, " K"]:
        """(K,) int32 the object's material slot of each used material ``albedo[k]``: the
        used-slot table (``used_slots``; slots 0..K-1 when not given). The network, the
        dataset and the metrics count used materials only (4 slots of which 2 are on faces
        give a 2-way material head); users see the slot (Passes.with_slots)."""
        if self.used_slots is None:
            return np.arange(self.material_count, dtype=np.int32)
        return np.asarray(self.used_slots, np.int32)

    @property
    def size(self) -> float:
        """Longest side of the AABB: one object unit (DESIGN section 2)."""
        return float(np.ptp(self.vertices, axis=0).max())

    @property
    def material_count(self) -> int:
        return len(self.albedo)

    @property
    def albedo_varies(self) -> bool:
        """True when albedo varies within a material, so the network needs an albedo head."""
        return any(a.kind != "constant" for a in self.albedo)

    def heads(self) -> dict[str, Any]:
        """Which attributes the scene needs the network to predict (DESIGN section 7)."""
        return {
            "occlusion": True,
            "distance": True,
            "normal": True,
            "albedo": self.albedo_varies,
            "material": self.material_count > 1,
            "material_count": self.material_count,
            "material_slots": self.material_slots.tolist(),
        }

    def albedo_table(self) -> Float[np.ndarray, "M 3"]:
        """(M, 3) constant albedo per material: the lookup table used without albedo head."""
        return np.array([a.color for a in self.albedo], dtype=np.float32)
