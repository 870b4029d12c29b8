"""The size limits of a run, one value each, read by the batch commands' validation and by
the core where it allocates. Each keeps one run within this machine class's memory (a few
GiB per buffer) with a clear error instead of a failed 200 GiB allocation.
"""

from __future__ import annotations

from .errors import VDNIFError

MAX_IMAGE_PIXELS = 4096 * 4096
"""Pixels of one rendered image: a ray costs about 1 KiB across the walk's buffers, the passes
and both references, so the cap keeps the worst image within this machine class's memory."""

MIN_OBJECT_SIZE = 1e-5
MAX_OBJECT_SIZE = 1e9
"""The supported sizes of a mesh (longest side of its rest bounds, local units; DESIGN section
2). Inside it every figure in object units is the same at any scale (tests/posed/test_scale.py);
outside, float32 parts of the pipeline under- or overflow, so such a mesh is refused."""

MAX_IMAGE_SIDE = 16384
MAX_POSES = 4096
"""Poses of one capture: the deformed corners are kept for every pose (``capture``)."""

MAX_RAYS_PER_POSE = 1 << 22
"""Training rays per pose: every walked segment is a dataset shard row, so the cap keeps one
pose's rows within a few GiB."""

MAX_SHARD_SEGMENTS = 64 * MAX_RAYS_PER_POSE
"""Segments (rows) of one dataset shard: ~6 poses of MAX_RAYS_PER_POSE rays at ~10 segments a
ray, ~21 GiB at ~80 bytes a row. Training reads a shard's arrays whole, so a shard whose zip
directory or array headers claim more is refused before any array is read."""

MAX_HEADER_BYTES = 1 << 28
"""Bytes of one dataset header or manifest (JSON, read whole): a header of MAX_POSES poses of
a rig of a hundred bones takes about 30 MB."""

MAX_LOG2_TABLE_SIZE = 24
"""Hash table rows per level 2^T: at the cap a many-level table and Adam's two moments take
several GiB."""

MAX_TABLE_FLOATS = 2**31 - 1
"""The encoder kernels index the table with int32: at most this many floats (8 GB) in all
levels."""

MAX_BATCH = 1 << 22
MAX_WAVE_SEGMENTS = 1 << 22
"""Segments of one neural-render wave: the walk's buffer, the network's inputs and its
answers take about 200 bytes a segment (under 1 GiB at the cap, where rays x 16 segments
would take many GiB at the largest image). A larger wave is split (fewer segments per ray,
then part of the rays at a time) into waves that give the same passes."""
MAX_SEED = 2**31 - 1
"""numpy's and torch's seeds are unsigned 32-bit, the panel's IntProperty a signed 32-bit
int: the smaller of the two."""


MAX_THREADS = 1024
"""Torch threads (``--threads``): more than the cores of today's largest machines; 2^31 makes
OpenMP fail to allocate its thread pool and hang."""

MAX_REPEATS = 1000
"""Timed repeats of one measurement (``--repeats``) and trainings of one experiment point
(``--seeds``): the medians settle within a few."""

MAX_FRAME = 1_048_574
"""Blender's last timeline frame (and -MAX_FRAME its first): ``frame_set`` clamps a frame
beyond it, so a pose there would not be the frame it names."""

GROUP_TIMEOUT_S, MAX_GROUP_TIMEOUT_S = 300.0, 86400.0
"""Seconds a process of a ``torchrun`` launch waits for the others, to join and at every
collective, before it stops with a line that says what it waited for (``--group-timeout``):
minutes, where torch's own default (30 minutes) looked like a hang."""

MAX_FRAMES = MAX_POSES
"""Frames of one range (``render --frames``): a frame is a pose, and every frame writes its
passes' files, so a range shares the poses' bound (a million frames would write millions of
files over hours)."""

MAX_INPUT_FILE_BYTES = 1 << 32
"""Bytes of a mesh file, a .blend, and every file one of them names (an OBJ's material
library and textures, a glTF's buffers and images): the largest scanned meshes are a few
hundred MB; a larger file (or a device that never ends) is refused before an importer reads
it whole."""

IMPORT_MIN_MEMORY = 2 << 30
IMPORT_MEMORY_PER_BYTE = 64
"""The memory budget of importing a mesh file or opening a .blend (in a child process,
``blender.trial_load``): this many bytes per byte of the file, at least IMPORT_MIN_MEMORY,
at most the machine's memory. Blender holds a loaded file in a few times its size; a small
file that unpacks to gigabytes (a gzip .blend of zeros) is stopped at the budget."""

IMPORT_MIN_SECONDS = 120
IMPORT_SECONDS_PER_MB = 1.0
"""The time budget of the same: IMPORT_MIN_SECONDS, and this many seconds more per MB of the
file (Blender imports a few tens of MB a second)."""


def check_range(name: str, value: float, low: float, high: float | None = None) -> None:
    """Raises VDNIFError unless ``low <= value`` and, given ``high``, ``value <= high``."""
    if value < low:
        raise VDNIFError(f"{name} {value} must be at least {low}")
    if high is not None and value > high:
        raise VDNIFError(f"{name} {value} is more than the limit {high:,} "
                         "(vdnif_addon/limits.py, settings.BOUNDS)")


def check_image(width: int, height: int) -> None:
    """Raises VDNIFError unless a ``width`` x ``height`` image is within the limits."""
    check_range("image width", width, 1, MAX_IMAGE_SIDE)
    check_range("image height", height, 1, MAX_IMAGE_SIDE)
    if width * height > MAX_IMAGE_PIXELS:
        raise VDNIFError(f"image {width}x{height} has {width * height:,} pixels, more than "
                         f"the limit {MAX_IMAGE_PIXELS:,} (vdnif_addon/limits.py)")
