"""Apply a speed/accuracy preset (fast, balanced, accurate) measured by the ``bench`` command."""

import bpy
from bpy.props import EnumProperty

from ..vdnif_addon.errors import VDNIFError
from ..vdnif_addon.presets import PRESET_NAMES, describe_preset, load_presets
from .common import VDNIFOperator


class VDNIF_OT_apply_preset(VDNIFOperator, bpy.types.Operator):
    """Set variant, resolution, hash grid, PE bands, width and steps from a bench preset"""

    bl_idname = "vdnif.apply_preset"
    bl_label = "Apply Preset"
    bl_options = {"REGISTER", "UNDO"}
    needs = ("mesh", "idle")

    preset: EnumProperty(name="Preset", items=[(name, name.title(), "") for name in PRESET_NAMES])

    @classmethod
    def description(cls, context, properties):
        """The tooltip: the preset's settings and what bench measured with them."""
        try:
            return describe_preset(properties.preset, load_presets())
        except VDNIFError as error:
            return f"{cls.__doc__}. {error}"

    def work(self, context, obj):
        presets = load_presets()
        obj.vdnif.apply_preset(presets[self.preset])
        return f"'{obj.name}': {describe_preset(self.preset, presets)}"


classes = (VDNIF_OT_apply_preset,)
