"""Scene capture: rest mesh, exact voxels and deformed corners for every pose."""

import time

import bpy
import numpy as np

from ..errors import VDNIFError
from ..geometry import voxels
from ..geometry.capture import SURFACE_BOUND, Capture
from ..memory import check_memory
from ..pose_sets import PoseSpec
from .deform import CornerDeformer, check_deformers
from .poses import make_poses, posed
from .read_mesh import check_mesh_object, deform_modifiers, read_rest_mesh


def capture(obj, resolution=32, spec=PoseSpec(), progress=None, deform_corners=True,
            follow=None):
    """Captures mesh object ``obj`` for the poses chosen by ``spec``.

    A mesh without deform modifiers is static mode: one pose, corners at rest; unless
    something else moves it over the frames (an animated shape key, a modifier with a time
    input), which the frames pose source follows (mode "animated"). ``corners_follow``
    records how the corners follow the mesh: ``follow``, else as ``deform.check_deformers``
    chooses.
    ``progress(done, total)`` is called after each pose. With ``deform_corners`` False the
    poses are chosen but their corners are left to the caller (``corners`` is None), for
    work that deforms one pose at a time anyway.
    """
    start = time.perf_counter()
    check_mesh_object(obj)
    follow = check_deformers(obj, follow)
    _check_rigs_invertible(obj)
    mesh = read_rest_mesh(obj)
    read_s = time.perf_counter()
    try:
        grid = voxels.build_grid(mesh.vertices, mesh.triangles, resolution)
    except VDNIFError as exc:
        raise VDNIFError(f"'{obj.name}': {exc}") from None
    voxel_s = time.perf_counter()
    modifiers = deform_modifiers(obj)
    rest = grid.corner_positions()
    if modifiers or follow in SURFACE_BOUND:
        if not modifiers and spec.source != "frames":
            raise VDNIFError(f"'{obj.name}' has no armature or lattice to pose, and moves "
                             "only over the frames: use the frames pose source")
        poses = make_poses(obj, modifiers, spec)
        mode = "+".join(sorted({m.type.lower() for m in modifiers})) or "animated"
        if deform_corners:
            check_corners_memory(obj, resolution, len(poses), len(rest))
        corners = (_deformed_corners(obj, rest, poses, progress, follow) if deform_corners
                   else None)
    else:
        poses = [{"frame": float(bpy.context.scene.frame_current)}]
        corners = rest[None]
        mode = "static"
    end = time.perf_counter()
    timings = {"read_mesh_s": read_s - start, "voxelize_s": voxel_s - read_s,
               "deform_s": end - voxel_s, "total_s": end - start}
    return Capture(mesh=mesh, grid=grid, mode=mode, poses=poses, corners=corners,
                   timings=timings, corners_follow=follow)


_FLOAT32_MAX = float(np.finfo(np.float32).max)
"""Blender stores an infinite location or scale as float32's largest number: as infinite."""


def _check_rigs_invertible(obj):
    """Raises VDNIFError when an armature or lattice deforming ``obj`` (or ``obj`` itself)
    has a world matrix that is not finite (a NaN or infinite location, rotation or scale, its
    own or a parent's: every deformed cell would be NaN) or has no inverse (scaled to 0 on
    an axis): poses and the rest map need its inverse."""
    for name, matrix in ((f"object '{obj.name}'", obj.matrix_world),
                         *((f"{m.type.lower()} '{m.object.name}' of '{obj.name}'",
                            m.object.matrix_world)
                           for m in deform_modifiers(obj) if m.object is not None)):
        if not (np.abs(np.array(matrix)) < _FLOAT32_MAX).all():
            raise VDNIFError(f"the {name} has a location, rotation or scale that is not a "
                             "finite number (NaN or infinite; its own or a parent's)")
        determinant = matrix.to_3x3().determinant()
        if not (np.isfinite(determinant) and abs(determinant) > 0):
            raise VDNIFError(f"the {name} is scaled to zero or to a non-finite size (its "
                             "matrix has no inverse): give it a non-zero scale")


def check_corners_memory(obj, resolution, poses, corners):
    """Raises a VDNIFError where the deformed corners of ``poses`` poses of ``obj`` at
    ``resolution``, ``corners`` a pose, do not fit in the memory available."""
    check_memory(f"capturing {poses:,} poses of '{obj.name}' at resolution {resolution} "
                 f"({corners:,} voxel corners a pose)", corners_bytes(poses, corners),
                 "lower --poses or --resolution")


def corners_bytes(poses, corners):
    """Bytes of the deformed corners a capture keeps: ``corners`` float64 points a pose,
    for each of ``poses``, and one pose's more while Blender deforms it."""
    return (poses + 1) * corners * 3 * 8


def _deformed_corners(obj, rest, poses, progress, follow):
    """(P, C, 3) the ``rest`` corners deformed by Blender for every pose."""
    corners = np.empty((len(poses), len(rest), 3))
    with CornerDeformer(obj, rest, follow) as deformer:
        for index, pose in enumerate(poses):
            with posed(pose):
                corners[index] = deformer.deformed()
            if not np.isfinite(corners[index]).all():
                raise VDNIFError(f"pose {index} of '{obj.name}' deforms its voxel corners to "
                                 "positions that are not finite numbers (a bone, lattice "
                                 "point or rig with a NaN or infinite transform?)")
            if progress is not None:
                progress(index + 1, len(poses))
    return corners
