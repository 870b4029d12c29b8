"""Apply a speed/accuracy preset (fast, balanced, accurate) measured by the ``bench`` command."""

import bpy
from bpy.props import EnumProperty

from ..vdnif_addon.errors import VDNIFError
from ..vdnif_addon.presets import PRESET_NAMES, describe_preset, read_presets
from .common import VDNIFOperator


class VDNIF_OT_apply_preset(VDNIFOperator, bpy.types.Operator):
    """Set variant, resolution, hash grid, PE bands, width and steps from a bench preset"""

    bl_idname = "vdnif.apply_preset"
    bl_label = "Apply Preset"
    bl_options = {"REGISTER", "UNDO"}
    needs = ("mesh", "idle")

    preset: EnumProperty(name="Preset", items=[(name, name.title(), "") for name in PRESET_NAMES])

    @classmethod
    def unavailable_presets(cls):
        """{name: why it cannot be applied} of the presets ``bench`` dropped, each one line
        that names it and gives bench's reason: ``poll`` is given no preset to tell them
        apart, so the panel disables their buttons and says why. Empty where the presets file
        cannot be read: applying a preset then reports why."""
        try:
            _, dropped = read_presets()
        except VDNIFError:
            return {}
        return {name: _dropped(name, reason) for name, reason in dropped.items()}

    @classmethod
    def description(cls, context, properties):
        """The tooltip: the preset's settings and what bench measured with them, or why bench
        dropped it."""
        try:
            presets, dropped = read_presets()
        except VDNIFError as error:
            return f"{cls.__doc__}. {error}"
        if properties.preset in dropped:
            return _dropped(properties.preset, dropped[properties.preset])
        return describe_preset(properties.preset, presets)

    def work(self, context, obj):
        presets, dropped = read_presets()
        if self.preset in dropped:
            raise VDNIFError(_dropped(self.preset, dropped[self.preset]))
        obj.vdnif.apply_preset(presets[self.preset])
        return f"'{obj.name}': {describe_preset(self.preset, presets)}"


def _dropped(name, reason):
    """The line that says preset ``name`` was dropped by bench for ``reason``."""
    return f"{name.title()} was dropped by bench, {reason}"


classes = (VDNIF_OT_apply_preset,)
