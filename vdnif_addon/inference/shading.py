"""The shaded pass: what a renderer's user sees of the passes, a diffuse surface lit by the
scene's light and its world (DESIGN section 10, *Shaded image*).

Per pixel that hits: albedo / pi times the light's irradiance, max(0, N.L) and the shadow
ray's answer, plus the albedo times the world's colour times the ambient occlusion; a pixel
that misses shows the world's colour. For a uniform world this is what Cycles' diffuse BSDF
returns (a Lambertian surface reflects albedo / pi of its irradiance; a uniform sky of
radiance W gives pi W times the unoccluded cosine-weighted fraction, the AO pass); glossy,
indirect bounces and emission are left out. A sun's strength is its irradiance (W/m^2); a
point light's is its power (W), radiating power / (4 pi) W/sr, so its irradiance falls off
with the inverse square of the distance in world units.

The image is compared as the user sees it: Blender's *Standard* view transform (the sRGB
transfer function) to 8-bit values. ``compare_shaded`` gives the PSNR of the linear values
and of those 8-bit values, and the share of pixels where a channel steps by more than
``VISIBLE_STEP`` (2/255).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..errors import VDNIFError
from ..passes import Passes, SecondaryPasses
from .metrics import PSNR_FLOOR_MSE
from .secondary import Light, SecondarySettings

if TYPE_CHECKING:
    from jaxtyping import Bool, Float

VISIBLE_STEP = 2
"""8-bit steps a channel may differ by before a user can tell the pixels apart."""
BLENDER_WORLD = (0.050876, 0.050876, 0.050876)
"""The world colour of Blender's default scene (linear)."""
DEFAULT_STRENGTH = math.pi
"""The irradiance of the default light (no sun or point light in the scene): a white surface
facing it shows 1.0."""


@dataclass(frozen=True)
class Lighting:
    """The light of the shaded pass: one ``Light`` (a sun's direction or a point light's
    position, local space), its ``strength`` (a sun's irradiance in W/m^2, a point light's
    power in W), its linear ``colour``, the world's linear colour, and ``unit_scale``: world
    units per local unit, for a point light's falloff."""

    light: Light = field(default_factory=Light)
    strength: float = DEFAULT_STRENGTH
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    world: tuple[float, float, float] = BLENDER_WORLD
    unit_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("colour", "world"):
            value = np.asarray(getattr(self, name), np.float64)
            if value.shape != (3,) or not np.all(np.isfinite(value)) or (value < 0).any():
                raise VDNIFError(f"lighting: its {name} {getattr(self, name)!r} is not three "
                                 "non-negative numbers")
        for name in ("strength", "unit_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise VDNIFError(f"lighting: its {name} {value!r} is not a non-negative "
                                 "number")
        if not self.unit_scale > 0:
            raise VDNIFError("lighting: its unit scale must be above 0")

    def describe(self) -> dict[str, object]:
        """The strengths and the world as the JSON reports state them (the light's place:
        ``SecondarySettings.describe``)."""
        return {"light_strength": self.strength, "light_colour": list(self.colour),
                "world_colour": list(self.world), "unit_scale": self.unit_scale}


def settings_lighting(settings: SecondarySettings) -> Lighting:
    """The shaded pass's ``Lighting`` of the secondary rays' ``settings``: theirs, or the
    default strength, colour and world with their light."""
    return Lighting(light=settings.light) if settings.lighting is None else settings.lighting


def irradiance(lighting: Lighting, points: Float[np.ndarray, "N 3"]
               ) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, "N 3"]]:
    """(unit directions towards the light (N, 3), its irradiance on a surface facing it, per
    colour channel (N, 3))."""
    towards, distance = lighting.light.towards(points)
    colour = lighting.strength * np.asarray(lighting.colour, np.float64)
    if lighting.light.direction is not None:
        return towards, np.broadcast_to(colour, points.shape).copy()
    world = np.maximum(distance * lighting.unit_scale, 1e-12)
    return towards, colour / (4.0 * math.pi * world[:, None] ** 2)


def shade(origins: Float[np.ndarray, "R 3"], directions: Float[np.ndarray, "R 3"],
          passes: Passes, secondary: SecondaryPasses, lighting: Lighting
          ) -> Float[np.ndarray, "R 3"]:
    """(R, 3) float32 linear radiance of each pixel of ``passes`` (primary rays ``origins``,
    unit ``directions``, local units) with ``secondary``'s AO and shadow answers."""
    world = np.asarray(lighting.world, np.float64)
    image = np.broadcast_to(world, (len(passes.hit), 3)).astype(np.float64)
    hit = passes.hit
    if not hit.any():
        return image.astype(np.float32)
    points, normal = hit_points(origins, directions, passes)
    towards, light = irradiance(lighting, points)
    cosine = np.clip((normal * towards).sum(1), 0.0, None)
    albedo = np.asarray(passes.albedo[hit], np.float64)
    direct = albedo / math.pi * light * (cosine * secondary.lit[hit])[:, None]
    ambient = albedo * world * np.asarray(secondary.ao[hit], np.float64)[:, None]
    image[hit] = direct + ambient
    return image.astype(np.float32)


def hit_points(origins: Float[np.ndarray, "R 3"], directions: Float[np.ndarray, "R 3"],
               passes: Passes) -> tuple[Float[np.ndarray, "H 3"], Float[np.ndarray, "H 3"]]:
    """(hit points, unit normals turned towards the primary ray's origin), (H, 3) each, of
    the rays of ``passes`` that hit (local units)."""
    hit = passes.hit
    points = origins[hit] + passes.distance[hit, None] * directions[hit]
    normal = np.asarray(passes.normal[hit], np.float64)
    # the side that faces the primary ray's origin, as the secondary rays leave it
    normal = np.where(((normal * directions[hit]).sum(1) > 0)[:, None], -normal, normal)
    return points, normal


def light_cosines(origins: Float[np.ndarray, "R 3"], directions: Float[np.ndarray, "R 3"],
                  passes: Passes, lighting: Lighting) -> Float[np.ndarray, " R"]:
    """(R,) float32 N.L of each hit of ``passes``: its normal turned towards the primary
    ray's origin, towards ``lighting``'s light from the hit; NaN on a miss. The terminator
    band is |N.L| < a width (``terminator_band``)."""
    cosine = np.full(len(passes.hit), np.nan, np.float32)
    if passes.hit.any():
        points, normal = hit_points(origins, directions, passes)
        towards, _ = lighting.light.towards(points)
        cosine[passes.hit] = (normal * towards).sum(1)
    return cosine


def in_band(cosines: Float[np.ndarray, " R"], width: float) -> Bool[np.ndarray, " R"]:
    """(R,) bool: the hits whose ``light_cosines`` lie in the terminator band |N.L| <
    ``width``; False on a miss."""
    return np.abs(np.nan_to_num(cosines, nan=np.inf)) < width


def shaded_views(primaries: dict[str, Passes], secondary: dict[str, SecondaryPasses],
                 origins: Float[np.ndarray, "R 3"], directions: Float[np.ndarray, "R 3"],
                 lighting: Lighting
                 ) -> tuple[dict[str, Float[np.ndarray, "R 3"]],
                            dict[str, Float[np.ndarray, " R"]]]:
    """({name: shaded image (R, 3)}, {name: ``light_cosines`` (R,)}) of each primary pass
    ``primaries`` (the prediction and the references, over the same rays) with its own
    secondary passes ``secondary[name]``: one shading for every one of them."""
    images = {name: shade(origins, directions, passes, secondary[name], lighting)
              for name, passes in primaries.items()}
    cosines = {name: light_cosines(origins, directions, passes, lighting)
               for name, passes in primaries.items()}
    return images, cosines


def display_8bit(linear: Float[np.ndarray, "... 3"]) -> np.ndarray:
    """Blender's *Standard* view transform of linear values (the sRGB transfer function,
    clipped to 0..1) as 8-bit values (uint8)."""
    value = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    encoded = np.where(value <= 0.0031308, 12.92 * value,
                       1.055 * np.power(value, 1.0 / 2.4) - 0.055)
    return np.round(encoded * 255.0).astype(np.uint8)


def compare_shaded(predicted: Float[np.ndarray, "R 3"], reference: Float[np.ndarray, "R 3"],
                   pixels: Bool[np.ndarray, " R"] | None = None
                   ) -> dict[str, float | int | None]:
    """Image errors of the shaded ``predicted`` against ``reference`` over every pixel (or
    ``pixels``): ``shaded_psnr`` in dB of the linear values clipped to 0..1 as the Standard
    view clips them (peak 1, the display's white), ``shaded_psnr_8bit`` of the 8-bit values
    the user sees (``display_8bit``, peak 255), each 100 dB where they are equal
    (``metrics.PSNR_FLOOR_MSE``); ``shaded_visible_rate``, the share of pixels where a
    channel differs by more than VISIBLE_STEP 8-bit steps; and ``shaded_pixels``."""
    if predicted.shape != reference.shape:
        raise ValueError(f"shaded images of shapes {predicted.shape} and {reference.shape}")
    linear = [np.clip(np.asarray(image, np.float64), 0.0, 1.0)
              for image in (predicted, reference)]
    a, b = display_8bit(predicted), display_8bit(reference)
    if pixels is not None:
        a, b, linear = a[pixels], b[pixels], [image[pixels] for image in linear]
    if not len(a):
        return {"shaded_psnr": None, "shaded_psnr_8bit": None, "shaded_visible_rate": None,
                "shaded_pixels": 0}
    difference = a.astype(np.int16) - b.astype(np.int16)

    def psnr(mse):
        return float(-10.0 * math.log10(max(mse, PSNR_FLOOR_MSE)))

    visible = (np.abs(difference) > VISIBLE_STEP).any(-1)
    return {"shaded_psnr": psnr(float(np.mean((linear[0] - linear[1]) ** 2))),
            "shaded_psnr_8bit": psnr(float(np.mean((difference / 255.0) ** 2))),
            "shaded_visible_rate": float(visible.mean()), "shaded_pixels": int(len(a))}


def terminator_band(normal: Float[np.ndarray, "R 3"], directions: Float[np.ndarray, "R 3"],
                    towards: Float[np.ndarray, "R 3"], width: float) -> Bool[np.ndarray, " R"]:
    """(R,) bool: pixels whose normal (turned to the primary ray's origin) lies within
    ``width`` of perpendicular to the light, |N.L| < width: where a small normal error flips
    whether the surface faces the light."""
    normal = np.where(((normal * directions).sum(1) > 0)[:, None], -normal, normal)
    return np.abs((normal * towards).sum(1)) < width


def shadow_split(predicted: SecondaryPasses, reference: SecondaryPasses,
                 band: Bool[np.ndarray, " R"]) -> dict[str, float | None]:
    """The shadow pass's false lit and false shadow rates (as ``metrics.compare_secondary``
    defines them) inside the terminator ``band`` (suffix ``_terminator``) and outside it
    (``_cast``: cast shadows, where the light meets the surface at a clear angle)."""
    both = predicted.hit & reference.hit
    result = {}
    for suffix, region in (("_terminator", band), ("_cast", ~band)):
        rows = both & region
        lit, shadowed = rows & reference.lit, rows & ~reference.lit
        result[f"shadow_false_lit_rate{suffix}"] = (
            float((shadowed & predicted.lit).sum() / shadowed.sum()) if shadowed.any()
            else None)
        result[f"shadow_false_shadow_rate{suffix}"] = (
            float((lit & ~predicted.lit).sum() / lit.sum()) if lit.any() else None)
        result[f"shadow_rays{suffix}"] = int(rows.sum())
    return result
