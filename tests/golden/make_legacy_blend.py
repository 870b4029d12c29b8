"""Writes ``legacy-settings.blend`` and ``legacy-settings.json``: a .blend saved by an older
VDNIF (run this script from that version's checkout) whose object carries a value other than
the default in every one of its settings, a packed model and a dataset folder, and the values
it set. ``tests/extension/test_legacy_blend.py`` opens it with today's extension and finds
everything there, so a change to the settings' declarations that renames a property (or
drops one) fails.

    python tests/golden/make_legacy_blend.py OUT_FOLDER

The model packed is ``golden/arm-render-model.vdnif``; the object is the arm demo scene's.
"""

import atexit
import json
import os
import pathlib
import shutil
import sys
import tempfile

REPO = pathlib.Path(__file__).resolve().parents[2]
MODULE = "bl_ext.dev.vdnif"


def other_value(prop, current):
    """A value of RNA property ``prop`` other than ``current``, inside its limits."""
    kind = prop.type
    if kind == "BOOLEAN":
        return not current
    if kind == "ENUM":
        names = [item.identifier for item in prop.enum_items]
        return next(name for name in reversed(names) if name != current)
    if kind == "INT":
        low, high = prop.hard_min, prop.hard_max
        return current + 1 if current + 1 <= high else max(low, current - 1)
    if kind == "FLOAT":
        low, high = prop.hard_min, prop.hard_max
        value = current * 0.5 if current else 0.25
        return min(max(value, low), high) if value != current else (low + high) / 2
    if kind == "STRING":
        return f"legacy {prop.identifier}"
    return None


def main(out):
    os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="vdnif-user-")
    folder = tempfile.mkdtemp(prefix="vdnif-repo-")
    atexit.register(shutil.rmtree, os.environ["BLENDER_USER_RESOURCES"], True)
    atexit.register(shutil.rmtree, folder, True)
    import bpy  # noqa: I001 - Blender's script modules come with it

    import addon_utils
    import importlib

    os.symlink(str(REPO), os.path.join(folder, "vdnif"))
    bpy.context.preferences.extensions.repos.new(name="dev", module="dev",
                                                 custom_directory=folder, source="USER")
    addon_utils.enable(MODULE, default_set=True, handle_error=print)
    scenes = importlib.import_module(f"{MODULE}.vdnif_addon.blender.scenes")
    storage = importlib.import_module(f"{MODULE}.storage")
    bpy.ops.wm.read_homefile(use_empty=True)
    obj = scenes.demo_scene("arm")
    settings, expected = obj.vdnif, {}
    # live_preview would start a handler on opening; the model fields are set by keep_model
    skipped = {"rna_type", "name", "preview", "live_preview", "model_storage", "model_path",
               "model_info"}
    for prop in settings.bl_rna.properties:
        name = prop.identifier
        if name in skipped or prop.is_readonly or getattr(prop, "is_array", False):
            continue
        value = other_value(prop, getattr(settings, name))
        if value is None:
            continue
        setattr(settings, name, value)
        expected[name] = getattr(settings, name)       # as Blender stored it (float32)
    model = REPO / "tests" / "golden" / "arm-render-model.vdnif"
    settings.model_storage = "PACKED"
    storage.keep_model(obj, model, {"note": "packed by make_legacy_blend"})
    expected["model_storage"] = "PACKED"
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    blend = out / "legacy-settings.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), compress=True)
    (out / "legacy-settings.json").write_text(json.dumps(
        {"object": obj.name, "settings": expected,
         "model_bytes": model.stat().st_size}, indent=1, sort_keys=True) + "\n")
    print(blend, blend.stat().st_size)


if __name__ == "__main__":
    main(sys.argv[1])
    sys.stdout.flush()
    os._exit(0)
