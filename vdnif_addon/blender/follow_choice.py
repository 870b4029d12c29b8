"""How the voxel corners of a mesh follow it in the poses it trains on: the copied armature
and lattice modifiers, or the surface binding (``deform``), chosen by the embedding error
each gives on development poses.

Where the armature and lattice modifiers are all that deform the mesh, both ways apply. The
copies deform the corners exactly as Blender deforms the mesh, except where Blender itself
does not deform the corners as the mesh around them: a lattice as thin as the mesh holds
every corner outside its box still while the mesh inside bends (a flat plate in a lattice
fitted to it keeps an embedding error of 0.002 object units at every resolution). The
binding moves the corners with the nearest surface instead. Both are measured as the
suggested resolution is (``resolution``: the embedded against the true reference of a few
development poses at a small view, distance MAE in object units and hit mismatch), and the
copies are kept unless the binding is better by a margin (``FOLLOW_MARGIN``, relative, and
``KNEE_TOLERANCE``, the measurement's noise): a tie keeps them. Anything else that deforms
the mesh leaves the binding alone (``deform.check_deformers``). Where a Subdivision Surface
or Multires ends the stack, the binding to its cage (whose cost per pose does not grow with
the subdivided count) and the binding to the subdivided surface are measured the same way,
and the cage is kept unless the subdivided surface is better by the margin: a coarse cage
misses the subdivision's rounding between its vertices. Otherwise nothing is measured.
Neither way can give a separate piece that an armature moves apart from the surface it
touches a motion of its own (``pieces.sliding``): the choice names such pieces.
"""

import dataclasses
import time

from ..geometry.capture import ARMATURE_COPY, EVALUATED_SURFACE, SUBDIVIDED_SURFACE
from ..pose_sets import DEVELOPMENT_POSES
from ..settings import FOLLOW_MARGIN, KNEE_TOLERANCE, SUGGEST_POSES, SUGGEST_VIEW_SIZE
from ..worker import DirectCalls
from .capture_scene import capture
from .deform import check_deformers, trailing_subdivision
from .pieces import describe_sliding, sliding
from .poses import evaluation_spec
from .read_mesh import check_mesh_object, deform_modifiers
from .resolution import embedding_errors


@dataclasses.dataclass(frozen=True)
class FollowChoice:
    """How the corners follow (``follow``, one of ``CORNERS_FOLLOW``), the measured
    ``errors`` ({follow: {"embedding_error": object units, "hit_mismatch": share}}; empty
    where only one way applies), the ``seconds`` the choice took, and the ``sliding``
    pieces that no way of following can give a motion of their own (``pieces.sliding``)."""

    follow: str
    errors: dict
    seconds: float
    sliding: tuple = ()

    def describe(self):
        """One line: the choice and the figures it was made on, and what slides."""
        slides = f"; {describe_sliding(self.sliding)}" if self.sliding else ""
        if not self.errors:
            return f"corners follow: {self.follow} (the only way that applies){slides}"
        figures = ", ".join(
            f"{name} {_figure(row['embedding_error'])} ({_figure(row['hit_mismatch'], 100)} "
            "% hit mismatch)" for name, row in self.errors.items())
        return (f"corners follow: {self.follow} (embedding error on development poses: "
                f"{figures}; {self.seconds:.1f} s){slides}")


def _figure(value, scale=1):
    return "none" if value is None else f"{value * scale:.2g}"


def better(surface, copy, margin=FOLLOW_MARGIN, tolerance=KNEE_TOLERANCE):
    """Whether the figures ``surface`` of the way that must earn its place (the binding,
    or the subdivided surface) beat those ``copy`` of the way kept on a tie (the copies, or
    the cage) (rows {embedding_error, hit_mismatch}): its distance error below the other's
    by the relative ``margin`` and the absolute ``tolerance["distance"]``, and its hit
    mismatch no worse beyond ``tolerance["hit_mismatch"]``. A missing figure never beats."""
    if None in (surface["embedding_error"], copy["embedding_error"]):
        return False
    closer = (surface["embedding_error"] * (1 + margin) + tolerance["distance"]
              < copy["embedding_error"])
    hits = (surface["hit_mismatch"] is not None and copy["hit_mismatch"] is not None
            and surface["hit_mismatch"] <= copy["hit_mismatch"] + tolerance["hit_mismatch"])
    return closer and hits


def choose_follow(obj, resolution, spec, poses=SUGGEST_POSES, size=SUGGEST_VIEW_SIZE,
                  calls=DirectCalls(), progress=None):
    """The FollowChoice for mesh object ``obj`` trained at ``resolution`` on the poses of
    ``spec``: measured on ``poses`` development poses (``pose_sets.DEVELOPMENT_POSES``)
    at ``size`` x ``size`` where both ways apply (module docstring). ``calls``: how Blender
    is read (in this thread, or from a worker on the main thread: ``worker.MainCalls``);
    ``progress(done, total)`` after each way measured."""
    start = time.perf_counter()
    only, rigged, subdivided, slides = calls.call(lambda: (
        check_mesh_object(obj), check_deformers(obj), bool(deform_modifiers(obj)),
        bool(trailing_subdivision(obj)), sliding(obj))[1:])
    if only == ARMATURE_COPY and rigged:
        kept, candidate = ARMATURE_COPY, EVALUATED_SURFACE
    elif only == EVALUATED_SURFACE and subdivided:
        kept, candidate = EVALUATED_SURFACE, SUBDIVIDED_SURFACE
    else:
        return FollowChoice(only, {}, time.perf_counter() - start, slides)
    development = evaluation_spec(spec, min(spec.count, poses), pose_set=DEVELOPMENT_POSES)
    errors = {}
    for follow in (kept, candidate):
        captured = calls.call(lambda: capture(obj, resolution, development,
                                              deform_corners=False, follow=follow))
        errors[follow] = embedding_errors(obj, captured, size, calls)
        if progress is not None:
            progress(len(errors), 2)
    chosen = candidate if better(errors[candidate], errors[kept]) else kept
    return FollowChoice(chosen, errors, time.perf_counter() - start, slides)
