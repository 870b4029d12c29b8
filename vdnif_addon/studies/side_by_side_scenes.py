"""The side-by-side study's scene names, apart from its timing code so that the batch parser
can list them without importing torch or Warp (most of a failing command's start-up)."""

from ..errors import VDNIFError

SUZANNE_LEVELS = (2, 3, 4, 5)     # Suzanne (968 triangles) subdivided: 15,744 .. 1,007,616
MILLION_LEVEL = 5                 # 'million': the 1 M-triangle scene, 1,007,616 triangles
SCENES = ("bunny", *(f"suzanne-{level}" for level in SUZANNE_LEVELS), "million", "arm",
          "lattice", "spot")


def scene_name(name):
    """The scene a name in ``SCENES`` stands for ('million' is suzanne-5)."""
    if name not in SCENES:
        raise VDNIFError(f"unknown scene '{name}': choose one of {', '.join(SCENES)}")
    return f"suzanne-{MILLION_LEVEL}" if name == "million" else name
