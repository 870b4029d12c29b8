"""VDNIF extension entry point: registers the operators and panels.

The pipeline itself lives in ``vdnif_addon`` and never depends on this module.
"""

from . import operators, panels

_modules = (operators, panels)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()
