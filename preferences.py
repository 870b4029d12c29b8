"""Add-on preferences: the default device, the status of PyTorch and Warp (the kernel compiler),
and both installed on request into the extension's user folder (never into the extension's
own folder). Compiled kernels are cached in the extension's user folder as well."""

import importlib
import importlib.util
import os
import subprocess
import sys

import bpy

from .vdnif_addon import declarations, dependencies, settings

DEVICES = declarations.DEVICE.enum_items()
"""The device enum's items: ``settings.DEVICES`` with their labels (``declarations``)."""
INSTALL_HINT = "Preferences > Add-ons > VDNIF > Install PyTorch and Warp"
WARP_REQUIREMENT = dependencies.WARP_REQUIREMENT

_torch_details = None                  # cached (version, cuda available) or an error line
_warp_details = None                   # cached version and kernel cache folder, or an error
install = {"process": None, "message": "", "plan": None}


def dependencies_folder() -> str:
    """The user folder torch is installed into (kept across extension updates)."""
    return bpy.utils.extension_path_user(__package__, path="site-packages", create=True)


def kernel_folder() -> str:
    """The user folder compiled kernels are cached in (per machine: see kernels.runtime)."""
    return bpy.utils.extension_path_user(__package__, path="kernels", create=True)


def torch_available() -> bool:
    """Whether torch can be imported, found without importing it."""
    return importlib.util.find_spec("torch") is not None


def warp_available() -> bool:
    """Whether Warp can be imported, found without importing it."""
    return importlib.util.find_spec("warp") is not None


def use_kernel_folder() -> None:
    """Points the kernel cache at ``kernel_folder``, unless ``$VDNIF_KERNEL_CACHE`` names one
    (batch runs and tests share a cache that way). Imports Warp, not torch; a no-op without
    Warp or once a kernel was compiled."""
    if warp_available():
        from .vdnif_addon.kernels import runtime

        if runtime.CACHE_ENV not in os.environ:
            runtime.set_cache_root(kernel_folder())


def warp_details() -> str:
    """'Warp 1.x, kernels cached in FOLDER' or why it cannot be used; imports Warp (cached)."""
    global _warp_details
    if _warp_details is None:
        try:
            from .vdnif_addon.kernels import runtime

            _warp_details = (f"Warp {runtime.wp.__version__}, kernels cached in "
                             f"{runtime.cache_dir()}")
        except Exception as exc:   # a broken install must not break the preferences
            _warp_details = f"Warp is installed but cannot be imported: {exc}"
    return _warp_details


def torch_details() -> str:
    """'PyTorch 2.x, CUDA available' or why it cannot be used; imports torch (cached)."""
    global _torch_details
    if _torch_details is None:
        try:
            import torch

            cuda = ("CUDA available" if torch.cuda.is_available() else
                    "no CUDA device: VDNIF trains and renders on the CPU")
            _torch_details = f"PyTorch {torch.__version__}, {cuda}"
        except Exception as exc:   # a broken install must not break the preferences
            _torch_details = f"PyTorch is installed but cannot be imported: {exc}"
    return _torch_details


def device(context: bpy.types.Context) -> str:
    """The device chosen in the preferences (one of ``settings.DEVICES``)."""
    return context.preferences.addons[__package__].preferences.device


def install_command(folder: str) -> list[str]:
    """pip installing Warp and torch into ``folder`` with Blender's own Python: PyTorch's
    CUDA build where there is an NVIDIA driver, else its CPU build (``dependencies.torch_plan``,
    kept in ``install`` for the messages that say which build it is)."""
    install["plan"] = dependencies.torch_plan()
    return dependencies.install_command(sys.executable, folder, install["plan"])


def start_install(background: bool) -> str:
    """Installs torch: synchronously in background mode, else as a process watched by a
    timer so the UI keeps running. Returns a message for the user."""
    folder = dependencies_folder()
    command = install_command(folder)
    environment = dict(os.environ, PYTHONNOUSERSITE="1")
    if background:
        done = subprocess.run(command, capture_output=True, text=True, env=environment)
        return _installed(done.returncode, done.stdout + done.stderr)
    log = open(os.path.join(folder, "install.log"), "w")
    install["process"] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                          env=environment, text=True)
    install["process"].log = log
    size = "several GB" if install["plan"] is not None and install["plan"].cuda else "about 1 GB"
    install["message"] = f"Installing PyTorch and Warp (several minutes, {size})..."
    if install["plan"] is not None:
        install["message"] += f" {install['plan'].note}"
    bpy.app.timers.register(_watch_install, first_interval=1.0)
    return install["message"]


def _watch_install() -> float | None:
    process = install["process"]
    if process.poll() is None:
        return 1.0
    process.log.close()
    with open(process.log.name) as log:
        _installed(process.returncode, log.read())
    install["process"] = None
    return None


def _installed(returncode: int, output: str) -> str:
    """The outcome of pip (``returncode``, ``output``): what it installed and its size, or
    why it failed."""
    global _torch_details, _warp_details
    _torch_details = _warp_details = None
    importlib.invalidate_caches()
    if returncode == 0 and torch_available() and warp_available():
        use_kernel_folder()
        plan = install["plan"]
        install["message"] = dependencies.installed_line(dependencies_folder(), plan)
        if plan is not None and not plan.cuda:
            install["message"] += f"; {plan.note}"
    else:
        lines = [line for line in output.splitlines() if line.strip()]
        install["message"] = "PyTorch install failed: " + (lines[-1] if lines else
                                                           f"pip exit code {returncode}")
    return install["message"]


class VDNIFPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    device: bpy.props.EnumProperty(name="Device", items=DEVICES,
                                   default=settings.DEFAULT_DEVICE,
                                   description="Device for objects whose device setting is "
                                               "'Preferences'")

    def draw(self, context: bpy.types.Context) -> None:
        layout = self.layout
        layout.prop(self, "device")
        box = layout.box()
        if torch_available():
            box.label(text=torch_details(), icon="CHECKMARK")
        else:
            box.label(text="PyTorch is not installed: VDNIF needs it to train and render",
                      icon="ERROR")
        if warp_available():
            box.label(text=warp_details(), icon="CHECKMARK")
        else:
            box.label(text="Warp is not installed: VDNIF compiles its kernels with it",
                      icon="ERROR")
        if not (torch_available() and warp_available()):
            box.operator("vdnif.install_dependencies", icon="IMPORT")
        if install["message"]:
            box.label(text=install["message"], icon="INFO")


def register() -> None:
    folder = dependencies_folder()
    if folder not in sys.path:
        sys.path.append(folder)
    bpy.utils.register_class(VDNIFPreferences)


def unregister() -> None:
    bpy.utils.unregister_class(VDNIFPreferences)
    if bpy.app.timers.is_registered(_watch_install):
        bpy.app.timers.unregister(_watch_install)
    folder = dependencies_folder()
    if folder in sys.path:
        sys.path.remove(folder)
