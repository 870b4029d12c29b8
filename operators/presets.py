"""Apply a speed/accuracy preset (fast, balanced, accurate) measured by the ``bench`` command."""

import bpy
from bpy.props import EnumProperty

from ..vdnif_addon.presets import PRESET_NAMES, SETTINGS, load_presets
from .common import VDNIFOperator


class VDNIF_OT_apply_preset(VDNIFOperator, bpy.types.Operator):
    """Set resolution, hash grid, PE bands, width and steps from a preset measured by bench"""

    bl_idname = "vdnif.apply_preset"
    bl_label = "Apply Preset"
    bl_options = {"REGISTER", "UNDO"}
    needs = ("mesh", "idle")

    preset: EnumProperty(name="Preset", items=[(name, name.title(), "") for name in PRESET_NAMES])

    def work(self, context, obj):
        chosen = load_presets()[self.preset]
        for name in SETTINGS:
            setattr(obj.vdnif, name, chosen[name])
        measured = ", ".join(f"{key} {value:.4g}" for key, value in chosen["measured"].items())
        return f"'{obj.name}': preset {self.preset} ({measured})"


classes = (VDNIF_OT_apply_preset,)
