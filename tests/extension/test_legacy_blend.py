"""A .blend saved by an older VDNIF opens with today's extension with everything in it: every
setting of the object (each set to a value other than its default, by
``golden/make_legacy_blend.py`` run from that version), the packed model, the dataset folder.
A setting whose property was renamed or dropped reads as its default and fails here."""

import json
import math
import pathlib
import shutil

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"


def test_a_blend_saved_by_an_older_version_keeps_its_settings_and_model(extension, core,
                                                                         tmp_path):
    import bpy

    expected = json.loads((GOLDEN / "legacy-settings.json").read_text())
    blend = tmp_path / "shot.blend"
    shutil.copyfile(GOLDEN / "legacy-settings.blend", blend)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    obj = bpy.data.objects[expected["object"]]
    settings = obj.vdnif
    names = {prop.identifier for prop in settings.bl_rna.properties}
    assert set(expected["settings"]) <= names, "a saved setting has no property today"
    # Its resolution was the user's: training after the upgrade keeps it, not a suggestion.
    assert "resolution" in expected["settings"] and not settings.resolution_auto
    for name, value in expected["settings"].items():
        now = getattr(settings, name)
        if isinstance(value, float):
            assert math.isclose(now, value, rel_tol=1e-6), name
        else:
            assert now == value, name
    storage = extension.storage
    assert storage.has_model(obj)
    path = storage.model_path(obj)
    assert path.stat().st_size == expected["model_bytes"]
    golden = core("model.model_file").load_model(GOLDEN / "arm-render-model.vdnif")[1]
    assert core("model.model_file").load_model(path)[1] == golden
    assert settings.dataset_dir == expected["settings"]["dataset_dir"]
