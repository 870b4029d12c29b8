"""The frame's multilayer EXR names its channels as Cycles names a render result's:
``ViewLayer.<pass>.<channel>``, a normal's channels X, Y, Z (a compositor's Normal socket and
OpenEXR readers take vectors by those letters, colours by R, G, B), read back from the file's
own header by a parser written here from the OpenEXR layout (no bpy)."""

import struct

import numpy as np

from vdnif_addon.inference.exr import multilayer_bytes
from vdnif_addon.passes import COMPOSITOR_PASSES, VIEW_LAYER

# Cycles' names for these passes in a multilayer EXR (Blender manual, Render Passes; an EXR
# Cycles wrote opens with the same channels).
CYCLES_CHANNELS = {
    "Combined": ("R", "G", "B", "A"), "Depth": ("Z",), "Normal": ("X", "Y", "Z"),
    "DiffCol": ("R", "G", "B"), "IndexMA": ("X",),
}


def header_channels(data):
    """The channel names of an EXR file's ``channels`` attribute (a chlist)."""
    magic, version = struct.unpack_from("<ii", data)
    assert magic == 20000630 and version & 0xFF == 2
    position, names = 8, []
    while data[position] != 0:
        end = data.index(b"\0", position)
        name = data[position:end].decode()
        kind_end = data.index(b"\0", end + 1)
        kind = data[end + 1:kind_end].decode()
        (size,) = struct.unpack_from("<i", data, kind_end + 1)
        value = data[kind_end + 5:kind_end + 5 + size]
        if name == "channels":
            assert kind == "chlist"
            cursor = 0
            while value[cursor] != 0:
                stop = value.index(b"\0", cursor)
                names.append(value[cursor:stop].decode())
                cursor = stop + 1 + 16          # pixel type, pLinear + 3 reserved, sampling
        position = kind_end + 5 + size
    return names


def test_the_frames_exr_names_its_channels_as_cycles_does():
    height, width = 3, 5
    passes = {name: np.zeros((height, width, len(letters)), np.float32)
              for name, letters in COMPOSITOR_PASSES.items()}
    names = header_channels(multilayer_bytes(passes, COMPOSITOR_PASSES, VIEW_LAYER))
    expected = {f"{VIEW_LAYER}.{name}.{letter}" for name, letters in CYCLES_CHANNELS.items()
                for letter in letters}
    assert VIEW_LAYER == "ViewLayer"
    assert set(names) == expected
    assert names == sorted(names, key=str.encode)     # the format stores them sorted
