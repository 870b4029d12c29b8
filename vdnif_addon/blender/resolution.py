"""The suggested voxel resolution of a mesh (``--resolution auto``, the panel's suggestion):
the knee of its measured embedding-error curve, raised for thin parts.

The embedding error is measured, not guessed: per candidate R, the true and the embedded
reference (``generate.reference_run``) of a few poses, compared as distance MAE in object
units (shares of the rest mesh's longest side) and as the hit masks' mismatch (1 - IoU).
The error falls steeply at coarse R and then flattens, noisily, rather than falling on:
the suggestion is the coarsest candidate within a margin of the best one (``knee``),
never the finest by default. It is held to a target in object units
(``EMBEDDING_TARGET``) and says when no candidate meets it. A part thinner than about two
voxels is raised past (``thin_floor``, the thickness measured on the rest mesh), and a
textured mesh is never suggested coarser than the recipe trains it
(``recipe_resolution``): its albedo needs the finer embedding
however small the distance error is.

The settings (``settings.py``): KNEE_MARGIN, relative (1.5x the best); KNEE_TOLERANCE,
absolute, below which differences are noise (distance in object units, hit mismatch as a
share of the rays); EMBEDDING_TARGET, object units (a few times below the network's own
distance error on the demo scenes, 0.0008-0.003); THIN_PART_SHARE of the
surface must span THIN_PART_VOXELS voxels; SUGGEST_POSES poses at SUGGEST_VIEW_SIZE^2.
"""

import dataclasses
import math

from ..kernels.thickness import thin_thickness, triangle_thickness
from ..pose_sets import DEVELOPMENT_POSES
from ..posed.generate import reference_run
from ..posed.pose_source import CalledReader
from ..settings import (
    EMBEDDING_TARGET,
    KNEE_MARGIN,
    KNEE_TOLERANCE,
    RECIPE,
    RESOLUTION_CANDIDATES,
    SUGGEST_POSES,
    SUGGEST_VIEW_SIZE,
    THIN_PART_SHARE,
    THIN_PART_VOXELS,
)
from ..worker import DirectCalls
from .capture_scene import capture
from .pose_reader import PoseReader
from .poses import evaluation_spec
from .read_mesh import read_rest_mesh


def recipe_resolution(obj):
    """The voxel resolution mesh object ``obj`` trains at unless told (``Recipe.resolution_for``):
    the recipe's, finer for a textured mesh."""
    return RECIPE.resolution_for(read_rest_mesh(obj).albedo_varies)


@dataclasses.dataclass(frozen=True)
class Floor:
    """The coarsest resolution a mesh is suggested: ``textured`` (the recipe's textured
    resolution for a textured mesh, else 0; candidates below it are not measured) and
    ``thin`` (the coarsest candidate at which the thin parts, ``thickness`` object units of
    an object ``size`` long, span THIN_PART_VOXELS voxels; 0 when none is thin)."""

    textured: int = 0
    thin: int = 0
    thickness: float = math.inf
    size: float = 0.0


def thin_floor(thickness, size, candidates=RESOLUTION_CANDIDATES, voxels=THIN_PART_VOXELS):
    """The coarsest of ``candidates`` (ascending) at which a part ``thickness`` thick spans
    ``voxels`` voxels of an object ``size`` long (voxel size = size / R); the finest when
    none does; 0 for no thin part (an infinite thickness)."""
    if not math.isfinite(thickness):
        return 0
    needed = voxels * size / max(thickness, 1e-30)
    return next((r for r in candidates if r >= needed), candidates[-1])


def resolution_floor(obj, candidates=RESOLUTION_CANDIDATES):
    """The Floor of mesh object ``obj``: textured or not, and its thin parts' thickness
    (``kernels.thickness``: the thickness THIN_PART_SHARE of the rest surface is thinner
    than)."""
    mesh = read_rest_mesh(obj)
    thickness = thin_thickness(*triangle_thickness(mesh.vertices, mesh.triangles),
                               THIN_PART_SHARE)
    return Floor(RECIPE.textured_resolution if mesh.albedo_varies else 0,
                 thin_floor(thickness, mesh.size, candidates), thickness, mesh.size)


def considered(candidates, floor):
    """The candidates tried from ``floor`` (a resolution) on (the finest one when none is as
    fine)."""
    return [r for r in candidates if r >= floor] or list(candidates[-1:])


def knee(table, margin=KNEE_MARGIN, tolerance=None):
    """The row of ``table`` (rows {resolution, embedding_error, hit_mismatch}, ascending
    resolution) that is the coarsest whose every error is at most the best row's times
    (1 + ``margin``) plus ``tolerance[name]`` (absolute: {"distance": object units,
    "hit_mismatch": share}; default 0). A missing error (None) counts as infinite."""
    tolerance = tolerance or {}
    columns = {"distance": "embedding_error", "hit_mismatch": "hit_mismatch"}

    def value(row, column):
        figure = row.get(column)
        return math.inf if figure is None else figure

    limits = {name: min(value(row, column) for row in table) * (1 + margin)
              + tolerance.get(name, 0.0) for name, column in columns.items()}
    return next((row for row in table
                 if all(value(row, column) <= limits[name] for name, column in columns.items())),
                table[-1])


@dataclasses.dataclass
class Suggestion:
    """A suggested resolution and why: the measured ``table`` (rows {resolution,
    embedding_error, hit_mismatch} per candidate tried), the ``knee`` row, the ``floor``
    it was raised to, and the ``target`` (object units) the chosen row is held to."""

    resolution: int
    table: list
    knee: dict
    floor: Floor
    target: float

    @property
    def row(self):
        """The chosen resolution's row of the table."""
        return next(row for row in self.table if row["resolution"] == self.resolution)

    @property
    def met(self):
        """Whether the chosen resolution's embedding error is at most the target."""
        error = self.row["embedding_error"]
        return error is not None and error <= self.target

    @property
    def none_met(self):
        """Whether no candidate tried meets the target."""
        return not any(row["embedding_error"] is not None
                       and row["embedding_error"] <= self.target for row in self.table)

    def record(self):
        """The suggestion as strict JSON: the choice, the curve it was read from (object
        units), the knee, the thin-part floor (thickness None where nothing is thin), the
        target and whether the choice meets it."""
        floor = dataclasses.asdict(self.floor)
        if not math.isfinite(floor["thickness"]):
            floor["thickness"] = None
        return {"resolution": self.resolution, "table": [dict(row) for row in self.table],
                "knee": self.knee["resolution"], "floor": floor, "target": self.target,
                "met": self.met}

    def describe(self):
        """One line: the choice, why, the curve and the target."""
        error = self.row["embedding_error"]
        why = (f"the coarsest within {1 + KNEE_MARGIN:g}x of the best embedding error")
        if self.resolution > self.knee["resolution"]:
            why = (f"raised from the knee {self.knee['resolution']}: parts "
                   f"{self.floor.thickness:.3g} units thick span {THIN_PART_VOXELS:g} voxels")
        curve = ", ".join(f"{row['resolution']}: {_figure(row['embedding_error'])}"
                          for row in self.table)
        verdict = ("meets" if self.met else
                   "no candidate meets" if self.none_met else "misses")
        return (f"{self.resolution} ({why}); embedding error {curve}; target "
                f"{self.target:.2g} object units: {verdict} it"
                + ("" if self.met else f" ({_figure(error)} at {self.resolution})"))


def _figure(value):
    return "none" if value is None else f"{value:.2g}"


def embedding_errors(obj, captured, size, calls=DirectCalls()):
    """{embedding_error, hit_mismatch} of ``captured`` (a capture of mesh object ``obj``,
    corners left to per-pose work): its embedded against its true reference
    (``generate.reference_run``) at ``size`` x ``size``, as distance MAE in object units and
    as 1 - the hit masks' IoU (None where neither hits). ``calls``: see
    ``suggest_resolution``."""
    reader = calls.call(lambda: PoseReader(obj, captured))
    try:
        report = reference_run(CalledReader(calls, reader), captured, size, size)
    finally:
        calls.call(reader.close, always=True)
    figures = report["embedded_vs_true"]
    iou = figures["hit_iou"]
    return {"embedding_error": figures["distance_mae"],
            "hit_mismatch": None if iou is None else 1.0 - iou}


def suggest_resolution(obj, spec, target=None, candidates=RESOLUTION_CANDIDATES,
                       poses=SUGGEST_POSES, size=SUGGEST_VIEW_SIZE, progress=None, floor=None,
                       calls=DirectCalls()):
    """The Suggestion for mesh object ``obj``: each of ``candidates`` (ascending) from the
    floor's textured resolution on is measured (embedding error and hit mismatch of the
    embedded against the true reference on ``poses`` development poses of the training
    ``spec``, a choice like every other: ``pose_sets``, at ``size`` x ``size``); the choice
    is their ``knee``, raised to the floor's thin-part resolution.
    ``target``: object units (default EMBEDDING_TARGET). ``floor``: a
    Floor, or a resolution below which nothing is tried (default ``resolution_floor``).

    ``calls``: how Blender is read (captures, poses): in this thread, or from a worker on
    the main thread (``worker.MainCalls``; ``floor`` must then be a Floor)."""
    if floor is None:
        floor = resolution_floor(obj, candidates)
    elif not isinstance(floor, Floor):
        floor = Floor(textured=floor)
    candidates = considered(candidates, floor.textured)
    table = []
    spec = evaluation_spec(spec, min(spec.count, poses), pose_set=DEVELOPMENT_POSES)
    for resolution in candidates:
        captured = calls.call(lambda: capture(obj, resolution, spec, deform_corners=False))
        table.append({"resolution": resolution,
                      **embedding_errors(obj, captured, size, calls)})
        if progress is not None:
            progress(resolution, table[-1]["embedding_error"])
    # The errors are in object units already (shares of the rest mesh's longest side).
    chosen = knee(table, tolerance=KNEE_TOLERANCE)
    resolution = max(chosen["resolution"], floor.thin)
    resolution = next((r for r in candidates if r >= resolution), candidates[-1])
    return Suggestion(resolution, table, chosen, floor,
                      EMBEDDING_TARGET if target is None else target)
