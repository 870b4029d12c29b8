"""The shaded pass on cases worked out by hand: a diffuse plane under a sun and under a point
light (inverse square in world units), its back side, shadow and AO, a miss; Blender's
Standard view transform at known codes; the image errors and the shadow rates split at the
terminator, counted by hand (no bpy)."""

import math

import numpy as np
import pytest

from vdnif_addon.errors import VDNIFError
from vdnif_addon.inference.secondary import Light
from vdnif_addon.inference.shading import (
    Lighting,
    compare_shaded,
    display_8bit,
    in_band,
    light_cosines,
    shade,
    shaded_views,
    shadow_split,
    terminator_band,
)
from vdnif_addon.passes import Passes, SecondaryPasses


def plane_pixels(normal_z=1.0, lit=True, ao=1.0, hit=True):
    """One ray straight down onto the plane z = 0 at the origin from z = 2, albedo (0.8,
    0.4, 0.2)."""
    origins, directions = np.array([[0.0, 0.0, 2.0]]), np.array([[0.0, 0.0, -1.0]])
    passes = Passes(hit=np.array([hit]), distance=np.array([2.0]),
                    normal=np.array([[0.0, 0.0, normal_z]], np.float32),
                    albedo=np.array([[0.8, 0.4, 0.2]], np.float32),
                    material=np.zeros(1, np.int32))
    secondary = SecondaryPasses(hit=np.array([hit]), ao=np.array([ao], np.float32),
                                lit=np.array([lit]), facing=np.array([True]))
    return origins, directions, passes, secondary


ALBEDO = np.array([0.8, 0.4, 0.2])
WORLD = np.array([0.1, 0.2, 0.3])


def test_a_plane_under_a_sun_at_sixty_degrees():
    sun = Light(direction=(math.sqrt(3) / 2, 0.0, 0.5), source="sun")     # cos 0.5 to +z
    lighting = Lighting(light=sun, strength=2.0, colour=(1.0, 0.5, 0.25), world=tuple(WORLD))
    expected = ALBEDO / math.pi * 2.0 * np.array([1.0, 0.5, 0.25]) * 0.5 + ALBEDO * WORLD
    np.testing.assert_allclose(shade(*plane_pixels(), lighting)[0], expected, rtol=1e-6)
    # seen from its back (the normal points away from the ray): the side facing the ray
    np.testing.assert_allclose(shade(*plane_pixels(normal_z=-1.0), lighting)[0], expected,
                               rtol=1e-6)
    np.testing.assert_allclose(shade(*plane_pixels(lit=False, ao=0.25), lighting)[0],
                               ALBEDO * WORLD * 0.25, rtol=1e-6)
    np.testing.assert_allclose(shade(*plane_pixels(hit=False), lighting)[0], WORLD, rtol=1e-6)


def test_a_point_light_falls_off_with_the_square_of_the_world_distance():
    point = Light(direction=None, position=(0.0, 0.0, 3.0), source="point")
    near = Lighting(light=point, strength=100.0, world=(0.0, 0.0, 0.0))
    value = shade(*plane_pixels(), near)[0]
    np.testing.assert_allclose(value, ALBEDO / math.pi * 100.0 / (4 * math.pi * 9.0),
                               rtol=1e-6)
    far = Lighting(light=point, strength=100.0, world=(0.0, 0.0, 0.0), unit_scale=2.0)
    np.testing.assert_allclose(shade(*plane_pixels(), far)[0], value / 4.0, rtol=1e-6)


def test_bad_lighting_is_refused():
    with pytest.raises(VDNIFError, match="world"):
        Lighting(world=(0.1, -1.0, 0.0))
    with pytest.raises(VDNIFError, match="strength"):
        Lighting(strength=math.nan)
    with pytest.raises(VDNIFError, match="unit scale"):
        Lighting(unit_scale=0.0)


def srgb_inverse(code):
    """The linear value whose sRGB encoding is ``code`` / 255 (the standard's decoding)."""
    v = code / 255.0
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


def test_the_standard_view_transform_at_known_codes():
    assert display_8bit(np.array([0.0, 1.0, 2.0, -1.0])).tolist() == [0, 255, 255, 0]
    assert display_8bit(np.array([0.5])).tolist() == [188]          # 0.7354 of 255
    assert display_8bit(np.array([0.0031308])).tolist() == [10]     # the linear part's end
    codes = np.arange(256)
    decoded = np.array([srgb_inverse(c) for c in codes])
    assert display_8bit(decoded).tolist() == codes.tolist()


def test_image_errors_counted_by_hand():
    reference = np.full((10, 3), srgb_inverse(100))
    assert compare_shaded(reference, reference) == {           # equal: the 100 dB floor
        "shaded_psnr": 100.0, "shaded_psnr_8bit": 100.0, "shaded_visible_rate": 0.0,
        "shaded_pixels": 10}
    predicted = reference.copy()
    predicted[3, 1] = srgb_inverse(103)           # three steps: seen
    predicted[7, 0] = srgb_inverse(102)           # two steps: not seen
    result = compare_shaded(predicted, reference)
    mse = ((3 / 255) ** 2 + (2 / 255) ** 2) / 30
    assert result["shaded_visible_rate"] == pytest.approx(0.1)
    assert result["shaded_psnr_8bit"] == pytest.approx(10 * math.log10(1 / mse))
    linear = ((srgb_inverse(103) - srgb_inverse(100)) ** 2
              + (srgb_inverse(102) - srgb_inverse(100)) ** 2) / 30
    assert result["shaded_psnr"] == pytest.approx(10 * math.log10(1 / linear))
    # above the display's white both clip to it: no error, as the user sees none
    assert compare_shaded(np.full((2, 3), 5.0), np.full((2, 3), 1.5))["shaded_psnr"] == 100.0
    pixels = np.zeros(10, bool)
    pixels[[3, 4]] = True
    assert compare_shaded(predicted, reference, pixels)["shaded_visible_rate"] == 0.5


def test_shadow_rates_split_at_the_terminator():
    towards = np.tile([0.0, 0.0, 1.0], (8, 1))
    directions = np.tile([0.0, 0.0, -1.0], (8, 1))
    tilt = np.array([0.05, 0.05, 0.05, 0.05, 0.9, 0.9, 0.9, 0.9])     # N.L of each pixel
    normal = np.stack([np.sqrt(1 - tilt ** 2), np.zeros(8), tilt], 1)
    band = terminator_band(normal, directions, towards, 0.1)
    assert band.tolist() == [True] * 4 + [False] * 4
    hit = np.ones(8, bool)
    reference = SecondaryPasses(hit=hit, ao=np.ones(8, np.float32),
                                lit=np.array([1, 0, 1, 0, 1, 1, 0, 0], bool), facing=hit)
    predicted = SecondaryPasses(hit=hit, ao=np.ones(8, np.float32),
                                lit=np.array([0, 1, 1, 0, 1, 0, 0, 1], bool), facing=hit)
    split = shadow_split(predicted, reference, band)
    assert split["shadow_false_lit_rate_terminator"] == 0.5      # of pixels 1, 3
    assert split["shadow_false_shadow_rate_terminator"] == 0.5   # of pixels 0, 2
    assert split["shadow_false_lit_rate_cast"] == 0.5            # of pixels 6, 7
    assert split["shadow_false_shadow_rate_cast"] == 0.5         # of pixels 4, 5
    assert split["shadow_rays_terminator"] == split["shadow_rays_cast"] == 4


def test_a_sun_straight_on_a_white_plane_gives_its_strength_over_pi():
    """Straight on (N.L = 1), a white plane with no world shows E / pi: the default light's
    strength pi gives 1.0, the display's white."""
    origins, directions, passes, secondary = plane_pixels()
    passes.albedo[:] = 1.0
    sun = Light(direction=(0.0, 0.0, 1.0), source="sun")
    lighting = Lighting(light=sun, world=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(shade(origins, directions, passes, secondary, lighting)[0],
                               [1.0, 1.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(
        shade(origins, directions, passes, secondary,
              Lighting(light=sun, strength=7.0, world=(0.0, 0.0, 0.0)))[0],
        [7.0 / math.pi] * 3, rtol=1e-6)


def test_a_shadowed_pixel_shows_only_the_world_times_albedo_times_ao():
    point = Light(direction=None, position=(0.0, 0.0, 3.0), source="point")
    lighting = Lighting(light=point, strength=1000.0, world=tuple(WORLD))
    for ao in (0.0, 0.4, 1.0):
        np.testing.assert_allclose(shade(*plane_pixels(lit=False, ao=ao), lighting)[0],
                                   ALBEDO * WORLD * ao, rtol=1e-6)


def test_light_cosines_and_the_band_of_tilted_planes():
    """N.L of hits on planes tilted by t away from a sun 60 degrees from overhead: cos(60 + t),
    the normal turned to the ray (one plane is seen from its back); a miss has none and is in
    no band."""
    tilt = np.radians([-60.0, 0.0, 27.0, 33.0])
    rays = len(tilt) + 1
    origins = np.tile([0.0, 0.0, 2.0], (rays, 1))
    directions = np.tile([0.0, 0.0, -1.0], (rays, 1))
    normal = np.zeros((rays, 3))
    normal[:-1] = np.stack([-np.sin(tilt), np.zeros(len(tilt)), np.cos(tilt)], 1)
    normal[1] *= -1                                   # its back: turned to the ray
    hit = np.array([True] * len(tilt) + [False])
    passes = Passes(hit=hit, distance=np.where(hit, 2.0, 0.0), normal=normal,
                    albedo=np.ones((rays, 3), np.float32), material=np.zeros(rays, np.int32))
    sun = Light(direction=(np.sin(np.radians(60.0)), 0.0, 0.5), source="sun")
    cosines = light_cosines(origins, directions, passes, Lighting(light=sun))
    np.testing.assert_allclose(cosines[:-1], np.cos(np.radians([0.0, 60.0, 87.0, 93.0])),
                               atol=1e-6)
    assert np.isnan(cosines[-1])
    assert in_band(cosines, 0.1).tolist() == [False, False, True, True, False]
    assert in_band(cosines, 0.05).tolist() == [False] * 5


def test_each_view_is_shaded_from_its_own_passes():
    origins, directions, lit_passes, lit = plane_pixels()
    _, _, dark_passes, dark = plane_pixels(lit=False, ao=0.5)
    lighting = Lighting(light=Light(direction=(0.0, 0.0, 1.0), source="sun"),
                        world=tuple(WORLD))
    images, cosines = shaded_views({"predicted": lit_passes, "true": dark_passes},
                                   {"predicted": lit, "true": dark}, origins, directions,
                                   lighting)
    np.testing.assert_allclose(images["predicted"][0], ALBEDO + ALBEDO * WORLD, rtol=1e-6)
    np.testing.assert_allclose(images["true"][0], ALBEDO * WORLD * 0.5, rtol=1e-6)
    assert cosines["predicted"][0] == cosines["true"][0] == pytest.approx(1.0)
