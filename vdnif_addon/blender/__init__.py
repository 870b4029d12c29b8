"""The thin layer that reads and poses Blender scenes; the only part of the core that imports bpy."""
