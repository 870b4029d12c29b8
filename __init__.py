"""VDNIF extension entry point: registers the preferences, the per-object settings, the
operators and the panels. Registering imports no torch: the panel says when it is missing.

The pipeline itself lives in ``vdnif_addon`` and never depends on this module.
"""

from . import operators, panels, preferences, properties

_modules = (preferences, properties, operators, panels)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()
