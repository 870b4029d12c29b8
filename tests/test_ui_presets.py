"""The panel's preset menu applies the presets the bench command measured."""

import json
import types

import pytest


def test_presets_set_the_objects_settings_and_a_bad_file_is_reported(empty_scene, core,
                                                                        tmp_path, monkeypatch):
    import bpy

    presets = core("presets")
    settings = dict(resolution=16, levels=4, log2_table_size=18, pe_bands=6, width=128,
                    steps=3000)
    measured = {presets.PRESET_ERROR: 0.1, "render_rays_per_s": 1e5}
    chosen = {name: dict(settings, width=16 * (i + 1), measured=measured)
              for i, name in enumerate(presets.PRESET_NAMES)}
    path = tmp_path / "presets.json"
    path.write_text(json.dumps({"source": "bench", "error": presets.PRESET_ERROR,
                                "presets": chosen}))
    monkeypatch.setattr(presets, "PRESETS_FILE", path)
    bpy.ops.mesh.primitive_cube_add()
    obj = bpy.context.active_object
    bpy.ops.vdnif.apply_preset(preset="balanced")
    for name, value in chosen["balanced"].items():
        if name != "measured":
            assert getattr(obj.vdnif, name) == value, name
    # The button's tooltip gives the settings and bench's figures, in the panel's words.
    tooltip = bpy.types.VDNIF_OT_apply_preset.description(
        bpy.context, types.SimpleNamespace(preset="balanced"))
    assert tooltip == ("Balanced: resolution 16, 4 hash-grid levels of 2^18 entries, 6 "
                       "positional-encoding bands, width 32, 3,000 steps; bench measured a "
                       "distance error of 0.1 object units and 100,000 rays/s")
    path.write_text("{}")
    with pytest.raises(RuntimeError, match="presets file .* cannot be read"):
        bpy.ops.vdnif.apply_preset(preset="fast")
    assert "'Cube'" in obj.vdnif.last_error and obj.vdnif.width == 32
    tooltip = bpy.types.VDNIF_OT_apply_preset.description(
        bpy.context, types.SimpleNamespace(preset="fast"))
    assert tooltip.startswith("Set resolution") and "cannot be read" in tooltip
