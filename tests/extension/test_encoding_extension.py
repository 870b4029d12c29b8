"""The encoder kernel's dependency in the extension: Warp installed beside PyTorch, shown in the
preferences with its kernel cache, and that cache kept in the extension's user folder."""

import os
import subprocess
import sys

import bpy
from conftest import ENABLE_IN_FRESH_PROCESS, EXTENSION_MODULE, REPO


def test_the_installer_installs_the_pinned_warp_beside_torch(extension):
    module = extension.preferences
    pinned = [line.strip() for line in (REPO / "requirements.txt").read_text().splitlines()
              if line.startswith("warp-lang")]
    assert pinned == [module.WARP_REQUIREMENT]
    command = module.install_command("/some/folder")
    assert command[-2:] == [module.WARP_REQUIREMENT, module.install["plan"].requirement]
    assert module.warp_available()


def test_preferences_show_the_warp_version_and_the_kernel_cache(extension, monkeypatch):
    import warp
    from test_ui_panels import RecordingLayout, texts
    from test_ui_register import PreferencesStandIn

    preferences = bpy.context.preferences.addons[EXTENSION_MODULE].preferences
    cls = extension.preferences.VDNIFPreferences
    record = []
    cls.draw(PreferencesStandIn(preferences, RecordingLayout(record)), bpy.context)
    drawn = texts({"": record})
    runtime = sys.modules[f"{EXTENSION_MODULE}.vdnif_addon.kernels.runtime"]
    assert f"Warp {warp.__version__}, kernels cached in {runtime.cache_dir()}" in drawn
    assert "operator:vdnif.install_dependencies" not in drawn  # both installed
    monkeypatch.setattr(extension.preferences, "warp_available", lambda: False)
    record.clear()
    cls.draw(PreferencesStandIn(preferences, RecordingLayout(record)), bpy.context)
    drawn = texts({"": record})
    assert "Warp is not installed" in drawn and "operator:vdnif.install_dependencies" in drawn


def _cache_after_enabling(environment):
    script = ENABLE_IN_FRESH_PROCESS + f"""
runtime = sys.modules["{EXTENSION_MODULE}.vdnif_addon.kernels.runtime"]
print("user folder:", bpy.utils.extension_path_user("{EXTENSION_MODULE}", path="kernels"))
print("cache:", runtime.cache_dir())
print("torch imported:", "torch" in sys.modules)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, env=environment)
    lines = dict(line.split(": ", 1) for line in done.stdout.splitlines() if ": " in line)
    assert lines.get("torch imported") == "False", done.stdout + done.stderr
    return lines


def test_registering_keeps_kernels_in_the_user_folder_unless_the_environment_names_one(
        tmp_path):
    environment = {key: value for key, value in os.environ.items()
                   if key != "VDNIF_KERNEL_CACHE"}
    lines = _cache_after_enabling(environment)
    assert lines["cache"].startswith(lines["user folder"] + os.sep + "warp-")
    lines = _cache_after_enabling(dict(environment, VDNIF_KERNEL_CACHE=str(tmp_path)))
    assert lines["cache"].startswith(str(tmp_path) + os.sep + "warp-")
