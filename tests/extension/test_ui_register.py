"""The extension registers and unregisters cleanly, without importing torch, and its
preferences offer to install torch into the extension's user folder."""

import subprocess
import sys

import bpy
import pytest
from conftest import ENABLE_IN_FRESH_PROCESS, EXTENSION_MODULE


def registered_state():
    """Everything of ours Blender could keep: classes, properties, operators, handlers,
    timers, import paths."""
    import addon_utils

    module = sys.modules[EXTENSION_MODULE]
    handlers = {name: len(getattr(bpy.app.handlers, name)) for name in dir(bpy.app.handlers)
                if isinstance(getattr(bpy.app.handlers, name), list)}
    return {
        "classes": sorted(name for name in dir(bpy.types) if name.startswith("VDNIF")),
        "object_settings": hasattr(bpy.types.Object, "vdnif"),
        "viewer": hasattr(bpy.types.Scene, "vdnif_viewer"),
        "operators": sorted(dir(bpy.ops.vdnif)),
        "handlers": handlers,
        "install_timer": bpy.app.timers.is_registered(module.preferences._watch_install),
        "dependency_path": module.preferences.dependencies_folder() in sys.path,
        "enabled": bool(addon_utils.check(EXTENSION_MODULE)[1]),
    }


def test_register_and_unregister_twice_leave_nothing_behind(extension):
    import addon_utils

    enabled = registered_state()
    assert enabled["classes"] and enabled["object_settings"] and enabled["viewer"]
    assert {"voxelize", "generate_dataset", "train", "estimate", "cancel_job",
            "render_passes", "render_animation", "evaluate", "save_model", "load_model",
            "install_dependencies", "apply_preset", "suggest_resolution"} == set(
                enabled["operators"])
    assert enabled["dependency_path"] and not enabled["install_timer"]
    handlers = dict(enabled["handlers"], load_post=enabled["handlers"]["load_post"] - 3,
                    frame_change_post=enabled["handlers"]["frame_change_post"] - 1)
    for _ in range(2):
        addon_utils.disable(EXTENSION_MODULE, default_set=True)
        disabled = registered_state()
        assert disabled == dict(enabled, classes=[], object_settings=False, viewer=False,
                                operators=[], handlers=handlers, dependency_path=False,
                                enabled=False)
        addon_utils.enable(EXTENSION_MODULE, default_set=True)
        assert registered_state() == enabled


def test_enabling_imports_no_torch():
    """In a fresh process: the panel must be able to say that torch is missing."""
    script = ENABLE_IN_FRESH_PROCESS + f"""
assert addon_utils.check("{EXTENSION_MODULE}")[1], "not enabled"
print("torch imported:", "torch" in sys.modules)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert "torch imported: False" in done.stdout, done.stdout + done.stderr


def test_preferences_and_the_torch_installer(extension):
    preferences = bpy.context.preferences.addons[EXTENSION_MODULE].preferences
    assert type(preferences).bl_idname == EXTENSION_MODULE and preferences.device == "auto"
    module = extension.preferences
    folder = module.dependencies_folder()
    assert "extensions" in folder and folder.endswith("site-packages")
    command = module.install_command(folder)
    assert command[:3] == [sys.executable, "-m", "pip"]
    assert command[-1] == module.install["plan"].requirement
    assert command[command.index("--target") + 1] == folder
    assert module.torch_available() and module.torch_details().startswith("PyTorch 2.")
    assert not bpy.ops.vdnif.install_dependencies.poll(), "torch is installed already"


def test_install_dependencies_runs_pip_and_reports_its_outcome(extension, monkeypatch,
                                                               tmp_path):
    """In background mode the install runs synchronously; pip is replaced by a stand-in."""
    module = extension.preferences
    monkeypatch.setitem(module.install, "message", "")
    monkeypatch.setattr(module, "install_command", lambda folder: [
        sys.executable, "-c", "import sys; print('ERROR: No matching distribution'); "
                              "sys.exit(1)"])
    monkeypatch.setattr(module, "torch_available", lambda: False)
    with pytest.raises(RuntimeError, match="PyTorch install failed: ERROR: No matching"):
        bpy.ops.vdnif.install_dependencies()
    installed = tmp_path / "torch"                 # the stand-in pip 'installs' this
    monkeypatch.setattr(module, "torch_available", installed.exists)
    monkeypatch.setattr(module, "install_command", lambda folder: [
        sys.executable, "-c", f"open({str(installed)!r}, 'w')"])
    assert bpy.ops.vdnif.install_dependencies() == {"FINISHED"}
    assert module.install["message"].startswith("Installed PyTorch 2.13.0")


class PreferencesStandIn:
    """``self`` for the preferences' draw: the real preferences with a recording layout."""

    def __init__(self, preferences, layout):
        self.preferences, self.layout = preferences, layout

    def __getattr__(self, name):
        return getattr(self.preferences, name)


def test_preferences_draw_the_torch_status(extension, monkeypatch):
    from test_ui_panels import RecordingLayout, texts

    preferences = bpy.context.preferences.addons[EXTENSION_MODULE].preferences
    cls = extension.preferences.VDNIFPreferences
    for available, expected in ((True, "PyTorch 2.13.0"),
                                (False, "operator:vdnif.install_dependencies")):
        monkeypatch.setattr(extension.preferences, "torch_available", lambda: available)
        record = []
        layout = RecordingLayout(record)
        cls.draw(PreferencesStandIn(preferences, layout), bpy.context)
        assert "prop:device" in texts({"": record}) and expected in texts({"": record})
