"""Writes images with Blender's own image API (PNG for looking, OpenEXR for data)."""

import pathlib

import bpy
import numpy as np

from ..safe_io import atomic_path

FORMATS = {".png": "PNG", ".exr": "OPEN_EXR"}


def save_image(path, image):
    """Saves (H, W, C) float32, row 0 at the top, C in 1..4; values are written as they are
    (Non-Color): PNG expects display-ready values in [0, 1], EXR keeps any float."""
    path = pathlib.Path(path)
    height, width, channels = image.shape
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :3] = image[..., :1] if channels == 1 else image[..., :3]
    if channels == 4:
        rgba[..., 3] = image[..., 3]
    if path.suffix == ".png":
        rgba = np.clip(np.nan_to_num(rgba), 0, 1)
    block = bpy.data.images.new(f"vdnif-save-{path.stem}", width, height, alpha=True,
                                float_buffer=True)
    try:
        block.colorspace_settings.name = "Non-Color"
        block.pixels.foreach_set(rgba[::-1].ravel())
        block.file_format = FORMATS[path.suffix]
        with atomic_path(path, "image") as temporary:     # safe_io: no partial image
            block.filepath_raw = temporary
            try:
                block.save()
            except RuntimeError as exc:
                raise OSError(str(exc)) from exc
    finally:
        bpy.data.images.remove(block)
    return path
