"""Install PyTorch and Warp into the extension's user folder (from the preferences or the
panel)."""

import bpy

from .. import preferences


class VDNIF_OT_install_dependencies(bpy.types.Operator):
    """Install PyTorch and Warp with pip into the extension's user folder (internet, minutes,
    about 1 GB; PyTorch's CUDA build where there is an NVIDIA driver, several GB on Linux)"""

    bl_idname = "vdnif.install_dependencies"
    bl_label = "Install PyTorch and Warp"

    @classmethod
    def poll(cls, context):
        if preferences.install["process"] is not None:
            cls.poll_message_set("PyTorch and Warp are being installed")
            return False
        if preferences.torch_available() and preferences.warp_available():
            cls.poll_message_set("PyTorch and Warp are already installed")
            return False
        return True

    def execute(self, context):
        message = preferences.start_install(bpy.app.background)
        failed = message.startswith("PyTorch install failed")
        self.report({"ERROR" if failed else "INFO"}, message)
        return {"CANCELLED" if failed else "FINISHED"}


classes = (VDNIF_OT_install_dependencies,)
