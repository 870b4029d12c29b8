"""The panel's preset menu applies the presets the bench command measured."""

import json

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
    path.write_text("{}")
    with pytest.raises(RuntimeError, match="presets file .* cannot be read"):
        bpy.ops.vdnif.apply_preset(preset="fast")
    assert "'Cube'" in obj.vdnif.last_error and obj.vdnif.width == 32
