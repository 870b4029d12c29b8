"""Images of per-ray passes for looking (display-ready RGB in [0, 1], previews transparent
where rays miss) and for use (the compositor's passes of the multilayer EXR), error heat
maps, and the reference | predicted | error comparison figure.

Every image is (H, W, C) float32 with row 0 at the top, as the camera rays are ordered.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..passes import COMPOSITOR_PASSES, MISS_DEPTH, SECONDARY_COMPOSITOR, SHADED_COMPOSITOR
from .shading import VISIBLE_STEP, display_8bit

if TYPE_CHECKING:
    from jaxtyping import Float

    from ..passes import Passes, SecondaryPasses

MISS_COLOR = np.array([0.05, 0.05, 0.06], np.float32)
# Anchors of a perceptual dark-to-bright heat map (magma-like), sampled evenly on [0, 1].
_HEAT = np.array([[0.001, 0.000, 0.014], [0.232, 0.060, 0.437], [0.550, 0.161, 0.506],
                  [0.868, 0.288, 0.409], [0.994, 0.624, 0.427], [0.987, 0.991, 0.750]],
                 np.float32)
_MATERIAL_PALETTE = np.array([[0.90, 0.60, 0.20], [0.20, 0.55, 0.90], [0.35, 0.80, 0.35],
                              [0.85, 0.30, 0.45], [0.65, 0.45, 0.85], [0.95, 0.85, 0.30],
                              [0.30, 0.80, 0.80], [0.60, 0.60, 0.60]], np.float32)
PASSES = ("normal", "albedo", "distance", "material")


def heat(values: Float[np.ndarray, "*batch"], vmax: float) -> Float[np.ndarray, "*batch 3"]:
    """(...,) values -> (..., 3) heat-map colors, 0 dark, ``vmax`` and above bright."""
    x = np.clip(np.nan_to_num(values / vmax if vmax > 0 else values * 0), 0, 1)
    position = x * (len(_HEAT) - 1)
    low = np.minimum(position.astype(int), len(_HEAT) - 2)
    weight = (position - low)[..., None]
    return ((1 - weight) * _HEAT[low] + weight * _HEAT[low + 1]).astype(np.float32)


def srgb(linear: Float[np.ndarray, "*batch"]) -> Float[np.ndarray, "*batch"]:
    """Linear RGB -> sRGB-encoded display values."""
    linear = np.clip(linear, 0, 1)
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * linear ** (1 / 2.4) - 0.055).astype(np.float32)


def display(passes: Passes, height: int, width: int, distance_range: tuple[float, float]
            ) -> dict[str, Float[np.ndarray, "H W 3"]]:
    """{pass name: (H, W, 3) display image} of Passes; misses are dark grey.

    Normals as (n + 1) / 2; albedo sRGB-encoded; distance nearer-is-brighter over
    ``distance_range`` = (near, far); material index by palette.
    """
    near, far = distance_range
    closeness = 1 - (passes.distance - near) / max(far - near, 1e-12)
    colors = {
        "normal": 0.5 * (passes.normal + 1),
        "albedo": srgb(passes.albedo),
        "distance": np.repeat(np.clip(0.15 + 0.85 * closeness, 0, 1)[:, None], 3, axis=1),
        "material": _MATERIAL_PALETTE[passes.material % len(_MATERIAL_PALETTE)],
    }
    return {name: _image(np.where(passes.hit[:, None], rgb, MISS_COLOR), height, width)
            for name, rgb in colors.items()}


def previews(passes: Passes, height: int, width: int, distance_range: tuple[float, float]
             ) -> dict[str, Float[np.ndarray, "H W 4"]]:
    """{pass name: (H, W, 4) preview}: the ``display`` images and the hit mask (white on
    black, so that a viewer that drops alpha still shows it), each with the hit mask as
    alpha, so that misses are transparent."""
    alpha = passes.hit.astype(np.float32)[:, None]
    shown = display(passes, height, width, distance_range)
    shown["hit"] = _image(np.repeat(alpha, 3, axis=1), height, width)
    return {name: np.concatenate([image, _image(alpha, height, width)], axis=2)
            for name, image in shown.items()}


def compositor_passes(passes: Passes, height: int, width: int,
                      normal_matrix: Float[np.ndarray, "3 3"] | None = None
                      ) -> dict[str, Float[np.ndarray, "H W C"]]:
    """{Cycles pass name: (H, W, C) float32} (``passes.COMPOSITOR_PASSES``) for a multilayer
    EXR: misses are 0 but in Depth (MISS_DEPTH) and transparent in Combined. Normals are
    mapped by ``normal_matrix`` (3, 3), the inverse transpose of the object's world matrix,
    when given (Cycles writes world-space normals), and normalized again."""
    hit = passes.hit[:, None]
    normal = passes.normal if normal_matrix is None else passes.normal @ np.asarray(
        normal_matrix, np.float64).T
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = normal / np.where(length > 0, length, 1.0)
    albedo = np.where(hit, passes.albedo, 0.0)
    data = {"Combined": np.concatenate([albedo, hit], axis=1),
            "Depth": np.where(passes.hit, passes.distance, MISS_DEPTH)[:, None],
            "Normal": np.where(hit, normal, 0.0),
            "DiffCol": albedo,
            "IndexMA": np.where(passes.hit, passes.material, 0)[:, None]}
    return {name: _image(data[name], height, width) for name in COMPOSITOR_PASSES}


def secondary_compositor(passes: SecondaryPasses, height: int, width: int,
                         names: Sequence[str]) -> dict[str, Float[np.ndarray, "H W 3"]]:
    """{Blender pass name: (H, W, 3) float32} of the secondary passes ``names`` ("ao",
    "shadow") for the multilayer EXR (``passes.SECONDARY_COMPOSITOR``): AO the unoccluded
    share, Shadow 1 lit and 0 shadowed, grey, 0 where nothing is hit."""
    values = {"ao": passes.ao, "shadow": passes.lit}
    return {title: _image(np.repeat(np.where(passes.hit, values[name], 0.0)[:, None], 3,
                                    axis=1), height, width)
            for title, name in SECONDARY_COMPOSITOR.items() if name in names}


def shaded_compositor(shaded: Float[np.ndarray, "R 3"], height: int, width: int
                      ) -> dict[str, Float[np.ndarray, "H W 3"]]:
    """{"Shaded": (H, W, 3) float32} (``passes.SHADED_COMPOSITOR``): the shaded image's
    linear values for the multilayer EXR."""
    (title,) = SHADED_COMPOSITOR
    return {title: _image(shaded, height, width)}


def shaded_display(shaded: Float[np.ndarray, "R 3"], height: int, width: int
                   ) -> Float[np.ndarray, "H W 3"]:
    """The shaded image as the user sees it (Blender's Standard view, 8-bit: the values
    ``shading.display_8bit`` gives, over 255), for the PNG preview and the pass viewer."""
    return _image(display_8bit(shaded) / np.float32(255.0), height, width)


def shaded_error(predicted: Float[np.ndarray, "R 3"], reference: Float[np.ndarray, "R 3"],
                 height: int, width: int, steps: float = 16.0) -> Float[np.ndarray, "H W 3"]:
    """Heat map of the shaded image's largest channel difference in 8-bit steps (bright at
    ``steps``); black where it is within ``shading.VISIBLE_STEP``, the steps nobody sees."""
    difference = np.abs(display_8bit(predicted).astype(np.int16)
                        - display_8bit(reference).astype(np.int16)).max(-1)
    shown = np.where(difference > VISIBLE_STEP, difference, 0).astype(np.float32)
    return _image(heat(shown, steps), height, width)


def error_images(predicted: Passes, reference: Passes, height: int, width: int,
                 object_size: float, distance_scale: float = 0.05, angle_scale: float = 45.0
                 ) -> dict[str, Float[np.ndarray, "H W 3"]]:
    """Heat maps of the errors where both hit: distance error (bright at ``distance_scale``
    object units) and normal angle (bright at ``angle_scale`` degrees); pixels where only
    one of them hits are white, where neither hits dark."""
    both = predicted.hit & reference.hit
    only_one = predicted.hit ^ reference.hit
    distance = np.abs(predicted.distance - reference.distance) / object_size
    cosine = np.clip((predicted.normal * reference.normal).sum(1), -1, 1)
    angle = np.degrees(np.arccos(cosine))
    images = {}
    for name, values, scale in (("distance", distance, distance_scale),
                                ("normal", angle, angle_scale)):
        rgb = np.where(both[:, None], heat(values, scale), MISS_COLOR)
        images[name] = _image(np.where(only_one[:, None], 1.0, rgb), height, width)
    material = np.where((predicted.material != reference.material)[:, None], 1.0, 0.0) * \
        np.array([1.0, 0.2, 0.2], np.float32)
    images["material"] = _image(np.where(both[:, None], material, MISS_COLOR), height, width)
    albedo = np.abs(predicted.albedo - reference.albedo).max(1)
    images["albedo"] = _image(np.where(both[:, None], heat(albedo, 0.25), MISS_COLOR),
                              height, width)
    return images


def secondary_images(passes: SecondaryPasses, height: int, width: int
                     ) -> dict[str, dict[str, Float[np.ndarray, "H W C"]]]:
    """{"display" | "raw": {"ao" | "shadow": image}}: grey levels for looking (misses dark),
    and the raw values (AO 0..1, shadow 1 lit / 0 shadowed, NaN where nothing is hit)."""
    values = {"ao": passes.ao.astype(np.float32), "shadow": passes.lit.astype(np.float32)}
    return {"display": {name: _image(np.where(passes.hit[:, None], value[:, None], MISS_COLOR),
                                     height, width) for name, value in values.items()},
            "raw": {name: _image(np.where(passes.hit, value, np.nan)[:, None], height, width)
                    for name, value in values.items()}}


def secondary_errors(predicted: SecondaryPasses, reference: SecondaryPasses, height: int,
                     width: int, ao_scale: float = 0.25) -> dict[str, Float[np.ndarray, "H W 3"]]:
    """Heat maps where both start from a hit: AO difference (bright at ``ao_scale``) and
    shadow disagreement (red: falsely lit, blue: falsely shadowed)."""
    both = (predicted.hit & reference.hit)[:, None]
    ao = heat(np.abs(predicted.ao - reference.ao), ao_scale)
    wrong = np.where((predicted.lit & ~reference.lit)[:, None], [1.0, 0.2, 0.2],
                     np.where((~predicted.lit & reference.lit)[:, None], [0.2, 0.4, 1.0], 0.0))
    return {"ao": _image(np.where(both, ao, MISS_COLOR), height, width),
            "shadow": _image(np.where(both, wrong, MISS_COLOR), height, width)}


def comparison_figure(rows: Sequence[Sequence[Float[np.ndarray, "H W C"]]], gap: int = 4
                      ) -> Float[np.ndarray, "FH FW 3"]:
    """One image (FH, FW, 3) from rows of equally sized images (reference | predicted | error
    per pass), separated by ``gap`` white pixels."""
    height, width = rows[0][0].shape[:2]
    figure = np.ones((len(rows) * (height + gap) - gap,
                      len(rows[0]) * (width + gap) - gap, 3), np.float32)
    for r, row in enumerate(rows):
        for c, image in enumerate(row):
            top, left = r * (height + gap), c * (width + gap)
            figure[top:top + height, left:left + width] = image[..., :3]
    return figure


def _image(values: Float[np.ndarray, "HW C"], height: int, width: int
           ) -> Float[np.ndarray, "H W C"]:
    return np.asarray(values, np.float32).reshape(height, width, -1)
