"""Secondary rays: ambient occlusion and shadow from each primary hit, answered by the
network (the deformed walk in waves, ``neural_render``), by the exact deformed mesh (a Warp
BVH, ``kernels.cast.MeshCaster``) or by the embedded reference (the walk and the exact
segment ground truth).

A secondary ray leaves the primary hit on the side of the normal turned towards the primary
ray's origin: started on the surface itself it would hit the surface it leaves (the classic
self-hit). It starts an offset above the tangent plane, reached along the ray itself
(``leave_surface``): a push along the normal would shift the ray sideways and a cast
shadow's edge with it. An exact hit's offset is ``SECONDARY_OFFSET`` object units (it is off
the surface by rounding only); the network's hit lies off the surface by its distance error,
so its offset is ``network_offset``, sized to the model's voxel and held-out error, and its
rays walk on past the surface they leave where its hit lay below it (``neural_occluded``).
Ambient occlusion casts ``samples`` cosine-weighted rays of that hemisphere up to
``distance`` object units from the hit; its pass is the fraction unoccluded. Shadow casts
one ray towards the light; a hit whose normal faces away from it is in its own shadow
without a cast.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import VDNIFError
from ..geometry.attributes import normalize
from ..passes import Passes, SecondaryPasses
from ..settings import (
    AO_DISTANCE,
    AO_SAMPLES,
    BOUNDS,
    DEFAULT_LIGHT_DIRECTION,
    SECONDARY_GRAZING_COSINE,
    SECONDARY_OFFSET,
    SECONDARY_OFFSET_ERRORS,
    SECONDARY_OFFSET_VOXELS,
    SECONDARY_SEED,
    SECONDARY_SELF_COSINE,
    SECONDARY_SELF_REACH,
    SECONDARY_SELF_SKIPS,
)
from ..tracing.rays import cosine_directions

if TYPE_CHECKING:
    from jaxtyping import Bool, Float, Int

    from ..geometry.restmesh import RestMesh
    from ..geometry.voxels import VoxelGrid
    from ..kernels.cells import DeviceCells
    from ..kernels.surface import SurfaceCaster
    from ..model.metadata import ModelMetadata
    from ..model.network import IntersectionNetwork

    Occluded = Callable[[Float[np.ndarray, "N 3"], Float[np.ndarray, "N 3"],
                         Float[np.ndarray, " N"], Float[np.ndarray, "N 3"],
                         Int[np.ndarray, " N"] | None],
                        Bool[np.ndarray, " N"]]
    """Whether rays (origins, unit directions, max distances; local units) hit anything;
    the fourth argument holds the unit normals (as their hits have them, unturned) of the
    surfaces the rays leave, the last the cells of those hits where the primary render
    walked cells (else None): a walk takes them as the cells its rays start in."""


@dataclass(frozen=True)
class Light:
    """The light a shadow ray goes to, in the object's local space: a direction towards it
    (a sun, or the default) or a position (a point light); ``source`` says which, for the
    output."""

    direction: tuple[float, float, float] | None = DEFAULT_LIGHT_DIRECTION
    position: tuple[float, float, float] | None = None
    source: str = "the default direction"

    def __post_init__(self) -> None:
        if (self.direction is None) == (self.position is None):
            raise VDNIFError(f"light {self.source}: give a direction or a position, not both")
        vector = self.direction if self.position is None else self.position
        if not (np.shape(vector) == (3,) and np.all(np.isfinite(vector))):
            raise VDNIFError(f"light {self.source}: {vector!r} is not three finite numbers")
        if self.direction is not None and not np.linalg.norm(self.direction) > 0:
            raise VDNIFError(f"light {self.source}: its direction has zero length")

    def towards(self, points: Float[np.ndarray, "N 3"]
                ) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, " N"]]:
        """(unit directions (N, 3), distances (N,)) from ``points`` to the light (inf for a
        direction; a point on the light itself gets distance 0)."""
        if self.direction is not None:
            unit = np.asarray(self.direction, np.float64) / np.linalg.norm(self.direction)
            return np.broadcast_to(unit, points.shape).copy(), np.full(len(points), np.inf)
        offset = np.asarray(self.position, np.float64) - points
        return normalize(offset, np.array([0.0, 0.0, 1.0])), np.linalg.norm(offset, axis=1)


@dataclass(frozen=True)
class SecondarySettings:
    """AO rays per pixel, their reach in object units, the light, the directions' seed, and
    the shaded pass's ``lighting`` (a ``shading.Lighting`` whose light is ``light``; None:
    its default strength, colour and world with ``light``)."""

    samples: int = AO_SAMPLES
    distance: float = AO_DISTANCE
    light: Light = field(default_factory=Light)
    seed: int = SECONDARY_SEED
    lighting: Any = None

    def __post_init__(self) -> None:
        low, high = BOUNDS["ao_samples"]
        if isinstance(self.samples, bool) or not low <= self.samples <= high:
            raise VDNIFError(f"AO samples {self.samples} must be an integer in {low}..{high}")
        low, high = BOUNDS["ao_distance"]
        if not (np.isfinite(self.distance) and low <= self.distance <= high):
            raise VDNIFError(f"AO distance {self.distance} must be in {low:g}..{high:g} "
                             "object units")
        if self.lighting is not None and self.lighting.light != self.light:
            raise VDNIFError(f"the shaded pass's light {self.lighting.light.source} is not "
                             f"the shadow rays' {self.light.source}")

    def describe(self, network_offset: float | None = None,
                 object_size: float = 1.0) -> dict[str, Any]:
        """The settings as the JSON reports state them, with the offsets in object units:
        the exact hits' and (``network_offset`` local units, when given; an object unit
        ``object_size`` local ones) the network's."""
        light = self.light
        return {"ao_samples": self.samples, "ao_distance": self.distance,
                "offset": SECONDARY_OFFSET,
                **({} if network_offset is None
                   else {"network_offset": network_offset / object_size}),
                "light": light.source,
                "light_direction": None if light.direction is None else list(light.direction),
                "light_position": None if light.position is None else list(light.position)}


# The walked paths end each ray at its max distance (``traverse``): the cell that crosses it
# comes whole, so its hit may lie beyond and is compared here.


def mesh_primary(vertices: Float[np.ndarray, "V 3"], triangles: Int[np.ndarray, "T 3"],
                 index: Int[np.ndarray, " R"], t: Float[np.ndarray, " R"]) -> Passes:
    """Passes of a classical caster's primary cast (``index`` the hit row of ``triangles``,
    -1 on a miss; ``t`` its distance): the hit, its distance and the hit triangle's
    geometric normal from the pose's ``vertices``."""
    hit = index >= 0
    passes = Passes.empty(len(index))
    passes.hit = hit
    passes.distance = np.where(hit, t, 0.0)
    corners = np.asarray(vertices, np.float64)[np.asarray(triangles)[index[hit]]]
    passes.normal[hit] = normalize(np.cross(corners[:, 1] - corners[:, 0],
                                            corners[:, 2] - corners[:, 0]),
                                   np.array([0.0, 0.0, 1.0]))
    return passes


def exact_occluded(caster: Any) -> Occluded:
    """Occlusion by a caster with ``cast(origins, directions, max_distance) -> (index, t)``
    (``MeshCaster`` of the deformed mesh; ``BruteForceCaster`` in the tests)."""
    def occluded(origins, directions, max_distance, leaving, start_cells=None):
        return caster.cast(origins, directions, max_distance)[0] >= 0
    return occluded


def embedded_occluded(cells: DeviceCells, mesh: RestMesh, rest_caster: SurfaceCaster
                      ) -> Occluded:
    """Occlusion as the embedded reference sees it: the walk through ``cells`` and the exact
    ground truth of its segments (what the network is trained to reproduce)."""
    from ..tracing.groundtruth import segment_targets
    from ..tracing.references import embedded_reference
    from ..tracing.traverse import traverse

    def occluded(origins, directions, max_distance, leaving, start_cells=None):
        segments = traverse(cells, origins, directions, max_distance,
                            start_cells=start_cells)
        targets = segment_targets(mesh, rest_caster, segments)
        passes = embedded_reference(cells, segments, targets, len(origins))
        return passes.hit & (passes.distance <= max_distance)
    return occluded


def neural_occluded(network: IntersectionNetwork, grid: VoxelGrid,
                    albedo_table: Float[np.ndarray, "M 3"], cells: DeviceCells,
                    offset: float, device: Any = "cpu", stats: dict[str, float] | None = None
                    ) -> Occluded:
    """Occlusion as the network answers it through the deformed walk, for rays started
    ``offset`` local units off the network's hits (``network_offset``); ``stats`` (when
    given) accumulates the rays and the seconds of its renders. A first hit within
    SECONDARY_SELF_REACH offsets whose normal lies within SECONDARY_SELF_COSINE of the left
    surface's is that surface, met from below where the network placed its hit under it:
    the ray walks on from an offset past it (at most SECONDARY_SELF_SKIPS times), started
    again within the same render (``neural_render.WalkPast``). An occluder met from outside
    faces the ray, and a crease's other side turns away."""
    # torch and Warp: imported here, so that the panel reads this module without them
    from .neural_render import WalkPast, neural_passes

    def occluded(origins, directions, max_distance, leaving, start_cells=None):
        start = time.perf_counter()
        reach = np.broadcast_to(np.asarray(max_distance, np.float64), (len(origins),))
        past = WalkPast(leaving=leaving, within=SECONDARY_SELF_REACH * offset, step=offset,
                        cosine=SECONDARY_SELF_COSINE, times=SECONDARY_SELF_SKIPS)
        passes, render = neural_passes(network, grid, albedo_table, cells, origins, directions,
                                       device, max_distance=reach, start_cells=start_cells,
                                       walk_past=past)
        blocked = passes.hit & (passes.distance <= reach - render["walked"])
        if stats is not None:
            stats["rays"] = stats.get("rays", 0) + len(origins)
            stats["seconds"] = stats.get("seconds", 0.0) + time.perf_counter() - start
        return blocked
    return occluded


def counted(occluded: Occluded, calls: list[int]) -> Occluded:
    """``occluded`` that appends the count of every batch of rays it answers to ``calls``
    (``secondary_passes`` asks for its AO and shadow rays in one batch)."""
    def counting(origins, directions, max_distance, leaving, start_cells=None):
        calls.append(len(origins))
        return occluded(origins, directions, max_distance, leaving, start_cells)
    return counting


def exact_offset(object_size: float) -> float:
    """How far (local units) the secondary rays of an exact hit start off it, an object unit
    ``object_size`` local ones: SECONDARY_OFFSET object units (the hit is off the surface by
    rounding only)."""
    return SECONDARY_OFFSET * object_size


def network_offset(object_size: float, voxel_size: float,
                   distance_mae_voxels: float | None = None) -> float:
    """How far (local units) the secondary rays of a network's hits start off them, for a
    model with voxels of ``voxel_size`` local units and its held-out distance MAE in voxels
    (None where training held out no poses): the most of an exact hit's offset,
    SECONDARY_OFFSET_VOXELS voxels and SECONDARY_OFFSET_ERRORS x that MAE."""
    voxels = max(SECONDARY_OFFSET_VOXELS, SECONDARY_OFFSET_ERRORS * (distance_mae_voxels or 0.0))
    return max(exact_offset(object_size), voxels * voxel_size)


def model_offset(metadata: ModelMetadata, object_size: float, voxel_size: float) -> float:
    """``network_offset`` of the model of ``metadata`` (its held-out distance MAE) over the
    capture's grid of ``voxel_size`` local units (equal to the model's)."""
    validation = metadata.training.validation or {}
    return network_offset(object_size, voxel_size, validation.get("distance_mae_voxels"))


def secondary_starts(primary: Passes, origins: Float[np.ndarray, "R 3"],
                     directions: Float[np.ndarray, "R 3"]
                     ) -> tuple[Float[np.ndarray, "H 3"], Float[np.ndarray, "H 3"]]:
    """(points (H, 3), unit normals (H, 3)) of the H primary hits of ``primary`` (rays
    ``origins`` + t ``directions`` (R, 3), local units), each normal turned towards its
    ray's origin: the side its secondary rays leave from."""
    hit = np.flatnonzero(primary.hit)
    direction = normalize(np.asarray(directions, np.float64)[hit], np.array([0.0, 0.0, 1.0]))
    point = np.asarray(origins, np.float64)[hit] + primary.distance[hit, None] * direction
    normal = normalize(primary.normal[hit], -direction)
    normal = np.where(((normal * direction).sum(1) > 0)[:, None], -normal, normal)
    return point, normal


def leave_surface(points: Float[np.ndarray, "N 3"], normals: Float[np.ndarray, "N 3"],
                  directions: Float[np.ndarray, "N 3"], offset: float
                  ) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, " N"]]:
    """(start points (N, 3), distances moved along the ray (N,)) of rays that leave
    ``points`` of the surface with unit ``normals`` in unit ``directions``: ``offset`` local
    units above the tangent plane, reached along the ray itself, which a push along the
    normal would shift sideways (and a shadow's edge with it); a ray that grazes the surface
    (cosine to the normal below SECONDARY_GRAZING_COSINE) moves at most
    offset / SECONDARY_GRAZING_COSINE along itself and the rest of the height along the
    normal."""
    cosine = (normals * directions).sum(1)
    along = offset / np.maximum(cosine, SECONDARY_GRAZING_COSINE)
    rest = np.maximum(offset - along * cosine, 0.0)
    return points + along[:, None] * directions + rest[:, None] * normals, along


def secondary_passes(primary: Passes, origins: Float[np.ndarray, "R 3"],
                     directions: Float[np.ndarray, "R 3"], occluded: Occluded,
                     object_size: float, settings: SecondarySettings = SecondarySettings(),
                     offset: float | None = None) -> SecondaryPasses:
    """AO and shadow of the primary hits of ``primary`` (rays (R, 3) in local units, an
    object unit ``object_size`` local ones) as ``occluded`` answers their secondary rays,
    started ``offset`` local units off the hits (by default an exact hit's,
    SECONDARY_OFFSET object units; ``network_offset`` for a network's hits).
    Pixel i's AO directions come from the same uniform numbers whoever renders it, so two
    renders of one view differ by their answers, not by their noise."""
    rays = len(primary.hit)
    if offset is None:
        offset = exact_offset(object_size)
    point, normal = secondary_starts(primary, origins, directions)
    leaving = normalize(primary.normal[primary.hit], normal)      # as the hits have them
    hit_cells = None if primary.cell is None else primary.cell[primary.hit]
    rng = np.random.default_rng([settings.seed, rays])
    uniform = rng.random((rays, settings.samples, 2))[primary.hit].reshape(-1, 2)
    samples = np.repeat(normal, settings.samples, axis=0)
    sampled = cosine_directions(samples, uniform)
    ao_start, ao_along = leave_surface(np.repeat(point, settings.samples, axis=0), samples,
                                       sampled, offset)
    towards, distance = settings.light.towards(point)
    facing = (normal * towards).sum(1) > 0
    shadow_start, shadow_along = leave_surface(point[facing], normal[facing], towards[facing],
                                               offset)
    # One batch, the AO rays then the shadow rays: a network answers them in one render.
    blocked = occluded(
        np.concatenate([ao_start, shadow_start]), np.concatenate([sampled, towards[facing]]),
        np.concatenate([settings.distance * object_size - ao_along,
                        distance[facing] - shadow_along]),
        np.concatenate([np.repeat(leaving, settings.samples, axis=0), leaving[facing]]),
        None if hit_cells is None else np.concatenate(
            [np.repeat(hit_cells, settings.samples), hit_cells[facing]]))
    ao = np.zeros(rays, np.float32)
    ao[primary.hit] = 1.0 - blocked[:len(ao_start)].reshape(-1, settings.samples).mean(1)
    lit_hits = facing.copy()
    lit_hits[facing] = ~blocked[len(ao_start):]
    lit, faces = np.zeros(rays, bool), np.zeros(rays, bool)
    lit[primary.hit], faces[primary.hit] = lit_hits, facing
    return SecondaryPasses(hit=primary.hit.copy(), ao=ao, lit=lit, facing=faces)


def secondary_views(primaries: dict[str, Passes], origins: Float[np.ndarray, "R 3"],
                    directions: Float[np.ndarray, "R 3"], occluders: dict[str, Occluded],
                    object_size: float, settings: SecondarySettings,
                    offset: float | None = None) -> dict[str, SecondaryPasses]:
    """The secondary passes an evaluation compares, from the primary ``primaries``
    {"predicted", "true", "embedded"} and the ``occluders`` {"neural", "exact",
    "embedded"}: "predicted" (the network from its own hits, started ``offset`` local
    units off them: ``network_offset``, needed with "predicted"), "true" and "embedded"
    (each reference from its own exact hits), and "predicted_true_hit" and
    "embedded_true_hit" (the network and the embedded reference from the true hits: their
    error is the secondary rays' own, without the primary hits')."""
    if "predicted" in primaries and offset is None:
        raise VDNIFError("the network's secondary rays need its offset (network_offset)")
    offsets = {"predicted": offset}         # the exact hits' own: secondary_passes' default
    plan = {"predicted": ("predicted", "neural"), "true": ("true", "exact"),
            "embedded": ("embedded", "embedded"), "predicted_true_hit": ("true", "neural"),
            "embedded_true_hit": ("true", "embedded")}
    return {name: secondary_passes(primaries[primary], origins, directions,
                                   occluders[occluder], object_size, settings,
                                   offsets.get(primary))
            for name, (primary, occluder) in plan.items()
            if primary in primaries and occluder in occluders}
