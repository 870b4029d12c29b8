"""The package loads as a Blender extension and unloads cleanly."""


def test_loaded_under_extension_namespace(extension):
    import addon_utils

    assert extension.__name__ == "bl_ext.dev.vdnif"
    assert addon_utils.check("bl_ext.dev.vdnif")[1], "extension is not enabled"
