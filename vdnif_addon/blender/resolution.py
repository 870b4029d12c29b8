"""The suggested voxel resolution of a mesh: the coarsest R whose voxel embedding costs
little next to the network's own error (``--resolution auto``, the panel's suggestion).

The embedding error is measured, not guessed: per candidate R, the true and the embedded
reference (``generate.reference_run``) of a few poses, compared as distance MAE in object
units. "The network's error" is known without training from the presets: each preset stores
the error its settings measured on a bench scene (``presets.json``, written by ``bench``).
A textured mesh is never suggested coarser than the recipe trains it (``recipe_resolution``):
its albedo needs the finer embedding however small the distance error is.
"""

import dataclasses

from ..posed.generate import reference_run
from ..posed.pose_source import CalledReader
from ..presets import PRESET_ERROR, load_presets
from ..settings import (
    EMBEDDING_ERROR_SHARE,
    RECIPE,
    RESOLUTION_CANDIDATES,
    SUGGEST_POSES,
    SUGGEST_PRESET,
    SUGGEST_VIEW_SIZE,
)
from ..worker import DirectCalls
from .capture_scene import capture
from .pose_reader import PoseReader
from .read_mesh import read_rest_mesh


def recipe_resolution(obj):
    """The voxel resolution mesh object ``obj`` trains at unless told (``Recipe.resolution_for``):
    the recipe's, finer for a textured mesh."""
    return RECIPE.resolution_for(read_rest_mesh(obj).albedo_varies)


def network_error(preset=SUGGEST_PRESET, presets=None):
    """The distance MAE (object units, against the true reference, ``PRESET_ERROR``) that
    ``preset``'s settings measured in the sweep that derived the presets."""
    chosen = (presets or load_presets())[preset]
    return float(chosen["measured"][PRESET_ERROR])


def resolution_floor(obj):
    """The coarsest resolution suggested for mesh object ``obj``: the textured one for a
    textured mesh, else none (0)."""
    return RECIPE.textured_resolution if read_rest_mesh(obj).albedo_varies else 0


def considered(candidates, floor):
    """The candidates tried from ``floor`` on (the finest one when none is as fine)."""
    return [r for r in candidates if r >= floor] or list(candidates[-1:])


def suggest_resolution(obj, spec, target=None, candidates=RESOLUTION_CANDIDATES,
                       poses=SUGGEST_POSES, size=SUGGEST_VIEW_SIZE, progress=None, floor=None,
                       calls=DirectCalls()):
    """(R, table): the coarsest of ``candidates`` (ascending) from ``floor`` on (default: the
    textured resolution for a textured mesh, else none) whose embedding error, distance
    MAE of the embedded against the true reference on ``poses`` poses of ``spec`` at
    ``size`` x ``size``, is at most ``target`` (default EMBEDDING_ERROR_SHARE of the
    preset's network error); the finest candidate when none is. ``table`` lists
    {resolution, embedding_error} per candidate tried.

    ``calls``: how Blender is read (captures, poses): in this thread, or from a worker on
    the main thread (``worker.MainCalls``; ``floor`` must then be given)."""
    if target is None:
        target = EMBEDDING_ERROR_SHARE * network_error()
    if floor is None:
        floor = resolution_floor(obj)
    candidates = considered(candidates, floor)
    table = []
    spec = dataclasses.replace(spec, count=min(spec.count, poses))
    for resolution in candidates:
        captured = calls.call(lambda: capture(obj, resolution, spec, deform_corners=False))
        reader = calls.call(lambda: PoseReader(obj, captured))
        try:
            report = reference_run(CalledReader(calls, reader), captured, size, size)
        finally:
            calls.call(reader.close, always=True)
        error = report["embedded_vs_true"]["distance_mae"]
        table.append({"resolution": resolution, "embedding_error": error})
        if progress is not None:
            progress(resolution, error)
        if error is not None and error <= target:
            return resolution, table
    return candidates[-1], table
