"""A multilayer OpenEXR writer: one scanline file of 32-bit float channels, ZIP-compressed,
named ``<layer>.<pass>.<channel>`` as Blender names render passes, so Blender's Image and
Compositor nodes open it as a multilayer image with one output per pass.

Written here rather than through a library: Blender's Python API saves a multilayer EXR only
from a render result (a registered render engine and a render), the OpenEXR bindings are not
shipped with Blender, and the format's scanline case is a header, an offset table and
zlib-compressed rows (openexr.com, "OpenEXR File Layout").
"""

from __future__ import annotations

import pathlib
import struct
import zlib
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..safe_io import write_bytes_atomic

if TYPE_CHECKING:
    from jaxtyping import Float

MAGIC = 20000630
FLOAT = 2                   # the channel pixel type: 32-bit IEEE float
ZIP_COMPRESSION = 3         # zlib over blocks of 16 scanlines
LINES_PER_BLOCK = 16


def _attribute(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _header(channels: Sequence[str], width: int, height: int) -> bytes:
    chlist = b"".join(name.encode() + b"\0" + struct.pack("<iB3xii", FLOAT, 0, 1, 1)
                      for name in channels) + b"\0"
    window = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    return b"".join([
        _attribute("channels", "chlist", chlist),
        _attribute("compression", "compression", bytes([ZIP_COMPRESSION])),
        _attribute("dataWindow", "box2i", window),
        _attribute("displayWindow", "box2i", window),
        _attribute("lineOrder", "lineOrder", b"\0"),             # increasing y
        _attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        _attribute("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
        _attribute("screenWindowWidth", "float", struct.pack("<f", 1.0)),
    ]) + b"\0"


def _compress(raw: bytes) -> bytes:
    """The ZIP codec: bytes split into even and odd positions, delta-coded, deflated; a block
    that does not shrink is stored as it is (readers tell by its size)."""
    data = np.frombuffer(raw, np.uint8)
    split = np.concatenate([data[0::2], data[1::2]])
    delta = split.astype(np.int16)
    delta[1:] = (split[1:].astype(np.int16) - split[:-1] + 128) & 0xFF
    packed = zlib.compress(delta.astype(np.uint8).tobytes(), 6)
    return packed if len(packed) < len(raw) else raw


def multilayer_bytes(passes: Mapping[str, Float[np.ndarray, "H W C"]],
                     channels: Mapping[str, str], layer: str) -> bytes:
    """The EXR file of ``passes`` {pass name: (H, W, C) image, row 0 at the top} in view
    layer ``layer``; ``channels`` {pass name: its C channel letters, e.g. "RGBA", "XYZ"}."""
    images = {name: np.asarray(image, np.float32) for name, image in passes.items()}
    height, width = next(iter(images.values())).shape[:2]
    planes = {}
    for name, image in images.items():
        if image.shape != (height, width, len(channels[name])):
            raise ValueError(f"pass {name} is {image.shape}, not ({height}, {width}, "
                             f"{len(channels[name])})")
        for index, letter in enumerate(channels[name]):
            planes[f"{layer}.{name}.{letter}"] = image[..., index]
    names = sorted(planes, key=str.encode)           # the format stores channels sorted
    # (H, channels, W): a scanline holds each channel's row in turn.
    rows = np.stack([planes[name] for name in names], axis=1).astype("<f4")
    blocks = []
    for top in range(0, height, LINES_PER_BLOCK):
        data = _compress(rows[top:top + LINES_PER_BLOCK].tobytes())
        blocks.append(struct.pack("<ii", top, len(data)) + data)
    start = (8 + len(_header(names, width, height))) + 8 * len(blocks)
    offsets = np.cumsum([start] + [len(block) for block in blocks[:-1]]).astype("<u8")
    return b"".join([struct.pack("<ii", MAGIC, 2), _header(names, width, height),
                     offsets.tobytes(), *blocks])


def write_multilayer(path: str | pathlib.Path, passes: Mapping[str, Float[np.ndarray, "H W C"]],
                     channels: Mapping[str, str], layer: str) -> pathlib.Path:
    """Writes ``multilayer_bytes`` to ``path`` atomically; returns the path."""
    return write_bytes_atomic(path, multilayer_bytes(passes, channels, layer), "EXR file")
