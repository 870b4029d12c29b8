"""The flat slab in a lattice fitted tightly around it, built by ``tools/resolution_meshes.py``
(one builder for the corner-follow tests and ``tools/corners_follow_choice.py``; a tool does
not import the tests). That module imports bpy and numpy, no copy of the core, so a Blender
test may use it beside ``core(...)``."""

import pathlib
import sys

sys.path.append(str(pathlib.Path(__file__).resolve().parents[2] / "tools"))

from resolution_meshes import thin_lattice_slab  # noqa: E402

__all__ = ["thin_lattice_slab"]
