"""The shaded pass as the renders write it: its channels in the frame's multilayer EXR (read
back from the file's own header), the toggles it depends on, and its images, computed from
hand-set passes (no bpy)."""

import numpy as np
from test_exr_channels import header_channels

from vdnif_addon.inference.exr import multilayer_bytes
from vdnif_addon.inference.images import shaded_compositor, shaded_display, shaded_error
from vdnif_addon.passes import (
    COMPOSITOR_PASSES,
    PASS_NEEDS,
    SECONDARY_COMPOSITOR,
    SHADED_COMPOSITOR,
    SHADED_PASS,
    TOGGLED_PASSES,
    VIEW_LAYER,
    cast_passes,
)


def test_the_shaded_pass_is_an_rgb_colour_beside_the_cycles_passes():
    height, width = 2, 3
    channels = {**COMPOSITOR_PASSES, **dict.fromkeys(SECONDARY_COMPOSITOR, "RGB"),
                **SHADED_COMPOSITOR}
    image = np.arange(height * width * 3, dtype=np.float32).reshape(-1, 3)
    layers = {name: np.zeros((height, width, len(letters)), np.float32)
              for name, letters in channels.items()}
    layers.update(shaded_compositor(image, height, width))
    names = header_channels(multilayer_bytes(layers, channels, VIEW_LAYER))
    assert {"ViewLayer.Shaded.R", "ViewLayer.Shaded.G", "ViewLayer.Shaded.B"} <= set(names)
    assert len(names) == len(set(names)) == 21     # 4 + 1 + 3 + 3 + 1, AO 3, Shadow 3, Shaded 3
    np.testing.assert_array_equal(layers["Shaded"][1, 2], image[5])   # row-major, row 0 top


def test_shaded_casts_the_ao_and_shadow_rays_it_is_made_of():
    assert TOGGLED_PASSES == ("ao", "shadow", SHADED_PASS)
    assert PASS_NEEDS[SHADED_PASS] == ("ao", "shadow")
    assert cast_passes(()) == ()
    assert cast_passes(("shadow",)) == ("shadow",)
    assert cast_passes((SHADED_PASS,)) == ("ao", "shadow")
    assert cast_passes(("ao", SHADED_PASS)) == ("ao", "shadow")


def test_the_shaded_images_show_what_the_user_sees():
    """The preview is the 8-bit Standard view; the error map is black within 2 steps."""
    linear = np.array([[0.0, 0.5, 1.0], [2.0, 0.2158605, 0.2158605]])   # code 128
    shown = shaded_display(linear, 1, 2)
    np.testing.assert_allclose(shown[0, 0], np.array([0, 188, 255]) / 255, rtol=1e-6)
    np.testing.assert_allclose(shown[0, 1], np.array([255, 128, 128]) / 255, rtol=1e-6)
    near = linear.copy()
    near[0, 1] = 0.5 * 1.01                 # one step in the display: not visible
    far = linear.copy()
    far[1, 1] = 0.3                         # many steps
    error = shaded_error(np.stack([near[0], far[1]]), linear, 1, 2)
    assert error[0, 0].max() < 0.02 and error[0, 1].max() > 0.2
