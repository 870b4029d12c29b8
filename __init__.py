"""VDNIF extension entry point: registers the preferences, the per-object settings, the
operators and the panels, and points the kernel cache at the extension's user folder.
Registering imports no torch (the panel says when it is missing); Warp, where installed.

The pipeline itself lives in ``vdnif_addon`` and never depends on this module.
"""

from . import operators, panels, preferences, properties, viewer
from .operators import live_preview

_modules = (preferences, properties, viewer, live_preview, operators, panels)


def register():
    for module in _modules:
        module.register()
    preferences.use_kernel_folder()  # kernels compile once per machine into the user folder


def unregister():
    for module in reversed(_modules):
        module.unregister()
