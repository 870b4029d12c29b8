"""Rays for reference renders and training, in the object's local (deformed) space.

Pinhole cameras (a look-at camera, a Blender camera matrix, orbits around the bounds), the
affine change of space with its distance scale (DESIGN section 2) and the training ray
distribution. Pure numpy; every direction returned is unit length.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .. import declarations as declared
from ..errors import VDNIFError
from ..geometry.attributes import normalize

if TYPE_CHECKING:
    from jaxtyping import Float

    Rays = tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, "N 3"]]
    """Ray origins and unit directions, N rays (H*W for an image, row-major)."""

# Orbit cameras keep this up vector unless it is parallel to the view direction.
DEFAULT_UP = np.array([0.0, 0.0, 1.0])

# Training ray origins lie on a sphere of this many half bounding-box diagonals.
TRAINING_RADIUS = 1.5

# Grazing training rays leave the tangent plane by at most this angle (degrees): holes hit at
# more than 75 deg to the normal (HOLES.md), so +-15 deg covers them and the near misses.
GRAZING_TILT_DEG = 15.0

# Of the rays that start on the surface, this share leaves into the hemisphere behind it, as a
# renderer's rays from a back face (an open mesh, a thin part seen from behind) do.
SECONDARY_BACK_SHARE = 0.25

# Golden angle in radians: the azimuth step of the Fibonacci sphere.
GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def look_at_rays(eye: Float[np.ndarray, "3"], target: Float[np.ndarray, "3"],
                 up: Float[np.ndarray, "3"], fov_deg: float, width: int, height: int) -> Rays:
    """Pinhole camera rays through pixel centres: origins (H*W, 3), unit directions (H*W, 3).

    Row-major with row 0 at the top of the image and x to the right; ``fov_deg`` is the
    horizontal field of view (the vertical one follows the aspect ratio). An ``up`` parallel
    to the view direction is replaced by the world axis least aligned with it.
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    length = np.linalg.norm(forward)
    if not length > 0:
        raise VDNIFError("camera target coincides with the camera position")
    forward = forward / length
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if not np.linalg.norm(right) > 1e-9 * np.linalg.norm(up):
        right = np.cross(forward, np.eye(3)[np.argmin(np.abs(forward))])
    right = right / np.linalg.norm(right)
    return _pinhole(eye, right, np.cross(right, forward), forward, fov_deg, width, height)


def camera_rays(camera_to_world: Float[np.ndarray, "4 4"], fov_deg: float, width: int,
                height: int, shift: tuple[float, float] = (0.0, 0.0)) -> Rays:
    """Rays (origins, unit directions), (H*W, 3) each, of a camera looking down its local -Z
    with +Y up (Blender's convention); layout as ``look_at_rays``. The matrix's axes are
    normalized first, so a scaled camera object renders as Blender does (it ignores scale).
    ``shift``: the image moved right and up by these fractions of its width (a lens
    shift)."""
    matrix = np.asarray(camera_to_world, dtype=np.float64)
    axes = matrix[:3, :3]
    lengths = np.linalg.norm(axes, axis=0)
    if not np.all(lengths > 0):
        raise VDNIFError("camera matrix has a zero-length axis")
    axes = axes / lengths
    return _pinhole(matrix[:3, 3], axes[:, 0], axes[:, 1], -axes[:, 2], fov_deg, width, height,
                    shift)


def _pinhole(eye: Float[np.ndarray, "3"], right: Float[np.ndarray, "3"],
             up: Float[np.ndarray, "3"], forward: Float[np.ndarray, "3"], fov_deg: float,
             width: int, height: int, shift: tuple[float, float] = (0.0, 0.0)) -> Rays:
    """Rays through the pixel centres of an image plane at distance 1 along ``forward``,
    moved by ``shift`` (right, up) image widths."""
    if width < 1 or height < 1:
        raise VDNIFError(f"image size must be at least 1x1, got {width}x{height}")
    half = _half_tan(fov_deg)
    x = ((np.arange(width) + 0.5) / width * 2 - 1) * half + 2 * shift[0] * half
    y = (1 - (np.arange(height) + 0.5) / height * 2) * half * height / width + (
        2 * shift[1] * half)
    directions = (forward + x[None, :, None] * right + y[:, None, None] * up).reshape(-1, 3)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return np.broadcast_to(eye, directions.shape).copy(), directions


def orbit_viewpoints(count: int, seed: int | None = None) -> Float[np.ndarray, "count 3"]:
    """(count, 3) unit directions: a deterministic Fibonacci sphere when ``seed`` is None,
    else uniform random on the sphere from ``np.random.default_rng(seed)``."""
    if count < 0:
        raise VDNIFError(f"viewpoint count must be >= 0, got {count}")
    if seed is None:
        index = np.arange(count)
        return _sphere_points(1 - (2 * index + 1) / count, index * GOLDEN_ANGLE)
    return _uniform_sphere(count, np.random.default_rng(seed))


def orbit_rays(bounds_lo: Float[np.ndarray, "3"], bounds_hi: Float[np.ndarray, "3"],
               direction: Float[np.ndarray, "3"], width: int, height: int, fov_deg: float = 40
               ) -> Rays:
    """Rays (origins, unit directions) of a camera on ``direction`` (3,) from the bounds
    centre, looking at it, just far enough that the bounding sphere fills the view cone
    inscribed in the image (half angle of the narrower of the horizontal/vertical fov)."""
    _, _, centre, radius = _bounds(bounds_lo, bounds_hi)
    direction = np.asarray(direction, dtype=np.float64)
    if not np.linalg.norm(direction) > 0:
        raise VDNIFError("orbit direction has zero length")
    half = _half_tan(fov_deg) * min(1.0, height / width)
    distance = radius / np.sin(np.arctan(half))
    eye = centre + distance * direction / np.linalg.norm(direction)
    return look_at_rays(eye, centre, DEFAULT_UP, fov_deg, width, height)


def transform_rays(origins: Float[np.ndarray, "N 3"], directions: Float[np.ndarray, "N 3"],
                   matrix: Float[np.ndarray, "4 4"]
                   ) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, "N 3"],
                              Float[np.ndarray, " N"]]:
    """Rays (N, 3) through the affine 4x4 ``matrix`` (e.g. the inverse world matrix).

    Returns origins', unit directions' and scale (N,) = |M_3x3 d| / |d|: a distance t' along
    the transformed ray is t' / scale along the original one (world distance = local distance
    / scale). A zero direction, or one the matrix maps to zero, gives direction 0 and scale 0.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    linear = matrix[:3, :3]
    directions = np.asarray(directions, dtype=np.float64)
    mapped = directions @ linear.T
    length = np.linalg.norm(directions, axis=1)
    mapped_length = np.linalg.norm(mapped, axis=1)
    valid = (length > 0) & (mapped_length > 0)
    scale = np.where(valid, mapped_length / np.where(valid, length, 1.0), 0.0)
    origins = np.asarray(origins, dtype=np.float64) @ linear.T + matrix[:3, 3]
    return origins, normalize(mapped, 0.0), scale


def training_rays(bounds_lo: Float[np.ndarray, "3"], bounds_hi: Float[np.ndarray, "3"],
                  surface_points: Float[np.ndarray, "S 3"], count: int, surface_fraction: float,
                  rng: np.random.Generator,
                  surface_normals: Float[np.ndarray, "S 3"] | None = None,
                  grazing_fraction: float = 0.0, grazing_tilt_deg: float = GRAZING_TILT_DEG,
                  secondary_fraction: float = 0.0, offset: float = 0.0) -> Rays:
    """Training rays (origins, unit directions), (count, 3) each, of three kinds at random
    positions in the batch (DESIGN section 8):

    - round(count * grazing_fraction) *grazing* rays through a random point of
      ``surface_points`` (S, 3) along a direction tangent to the surface there (normal from
      ``surface_normals`` (S, 3)), tilted out of the tangent plane by an angle uniform in
      +-``grazing_tilt_deg``; they start outside the sphere below. Silhouette rays: the
      holes and extras of a network trained without them are grazing rays that dip into, or
      pass just by, an edge (docs/HOLES.md measured 77 % of holes at more than
      75 deg to the normal);
    - round(count * surface_fraction) rays from the sphere aimed at a random surface point;
    - round(count * secondary_fraction) *secondary* rays that start on the surface, as a
      renderer's shadow and occlusion rays do: at a random point of ``surface_points``
      pushed ``offset`` (local units) along its normal, leaving in a cosine-weighted
      direction of that hemisphere; SECONDARY_BACK_SHARE of them start on the other side
      and leave into the other hemisphere. The walk starts them inside a cell;
    - the rest from the sphere aimed at a uniform random point in the box.

    Sphere origins are uniform on the sphere of radius 1.5 half bounding-box diagonals
    around the box centre.
    """
    shares = (("surface_fraction", surface_fraction), ("grazing_fraction", grazing_fraction),
              ("secondary_fraction", secondary_fraction))
    for name, value in shares:
        low, high = declared.BY_NAME[name].range
        if not low <= value <= high:
            raise VDNIFError(f"{name} must be in [{low:g}, {high:g}], got {value}")
    if sum(value for _, value in shares) > 1:
        raise VDNIFError("surface_fraction + grazing_fraction + secondary_fraction must be at "
                         f"most 1, got {' + '.join(str(value) for _, value in shares)}")
    if not (np.isfinite(offset) and offset >= 0):
        raise VDNIFError(f"surface offset must be a finite number >= 0, got {offset}")
    if count < 0:
        raise VDNIFError(f"ray count must be >= 0, got {count}")
    lo, hi, centre, radius = _bounds(bounds_lo, bounds_hi)
    surface_points = np.asarray(surface_points, dtype=np.float64).reshape(-1, 3)
    kind = rng.permutation(count)
    ends = np.cumsum([round(count * grazing_fraction), round(count * surface_fraction),
                      round(count * secondary_fraction)])
    grazing = kind < ends[0]
    on_surface = (kind >= ends[0]) & (kind < ends[1])
    secondary = (kind >= ends[1]) & (kind < ends[2])
    if (on_surface.any() or grazing.any() or secondary.any()) and len(surface_points) == 0:
        raise VDNIFError("surface rays requested but no surface points were given")
    if (grazing.any() or secondary.any()) and (
            surface_normals is None or np.shape(surface_normals) != surface_points.shape):
        raise VDNIFError("grazing and secondary rays need one surface normal per surface "
                         "point")
    origins = centre + TRAINING_RADIUS * radius * _uniform_sphere(count, rng)
    targets = lo + rng.random((count, 3)) * (hi - lo)
    targets[on_surface] = surface_points[rng.integers(len(surface_points),
                                                      size=on_surface.sum())]
    # A target on an origin (possible only for a surface point outside the sphere) aims inward.
    directions = normalize(targets - origins, normalize(centre - origins, 0.0))
    if grazing.any():
        chosen = rng.integers(len(surface_points), size=grazing.sum())
        points = surface_points[chosen]
        along = _grazing_directions(np.asarray(surface_normals, np.float64)[chosen],
                                    grazing_tilt_deg, rng)
        # Start beyond the sphere: |point - centre| + sphere radius is outside it.
        back = np.linalg.norm(points - centre, axis=1) + TRAINING_RADIUS * radius
        origins[grazing] = points - back[:, None] * along
        directions[grazing] = along
    if secondary.any():
        chosen = rng.integers(len(surface_points), size=secondary.sum())
        side = np.where(rng.random(len(chosen)) < SECONDARY_BACK_SHARE, -1.0, 1.0)[:, None]
        normal = side * normalize(np.asarray(surface_normals, np.float64)[chosen],
                                  np.array([0.0, 0.0, 1.0]))
        origins[secondary] = surface_points[chosen] + offset * normal
        directions[secondary] = cosine_directions(normal, rng.random((len(chosen), 2)))
    return origins, directions


def cosine_directions(normals: Float[np.ndarray, "N 3"], uniform: Float[np.ndarray, "N 2"]
                      ) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit directions in the hemispheres of unit ``normals`` (N, 3), distributed with
    density cos(theta) / pi when ``uniform`` (N, 2) is uniform in [0, 1)^2: a uniform point
    of the unit disk (radius sqrt(u0), azimuth 2 pi u1) lifted onto the hemisphere (Malley).
    The same ``uniform`` under two normals gives corresponding directions, so renders of
    nearby normals share their noise."""
    normals = np.asarray(normals, np.float64)
    uniform = np.asarray(uniform, np.float64)
    radius, azimuth = np.sqrt(uniform[:, 0]), 2 * np.pi * uniform[:, 1]
    tangent, bitangent = _frame(normals)
    local = (radius * np.cos(azimuth), radius * np.sin(azimuth),
             np.sqrt(np.clip(1.0 - uniform[:, 0], 0.0, None)))
    return normalize(local[0][:, None] * tangent + local[1][:, None] * bitangent
                     + local[2][:, None] * normals, normals)


def _frame(normals: Float[np.ndarray, "N 3"]
           ) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, "N 3"]]:
    """Two unit tangents completing unit ``normals`` (N, 3) to right-handed orthonormal
    frames, continuous except where z = -1 (Duff et al. 2017, branch on the sign of z)."""
    x, y, z = normals[:, 0], normals[:, 1], normals[:, 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tangent = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=1)
    bitangent = np.stack([b, sign + y * y * a, -y], axis=1)
    return tangent, bitangent


def _grazing_directions(normals: Float[np.ndarray, "N 3"], tilt_deg: float,
                        rng: np.random.Generator) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit directions tangent to the planes of ``normals`` (N, 3) (any length; a zero
    normal gives a uniform random direction) in a uniform random azimuth, tilted towards the
    normal by an angle uniform in +-``tilt_deg``."""
    if not 0 <= tilt_deg <= 90:
        raise VDNIFError(f"grazing tilt must be in [0, 90] degrees, got {tilt_deg}")
    count = len(normals)
    random = _uniform_sphere(count, rng)
    normal = normalize(normals, 0.0)
    normal = np.where((np.linalg.norm(normal, axis=1) > 0)[:, None], normal, random)
    # Any vector not parallel to the normal gives a tangent; a random one gives a uniform
    # azimuth. Redraw the rare near-parallel ones with a fixed axis least aligned.
    helper = _uniform_sphere(count, rng)
    tangent = np.cross(normal, helper)
    weak = np.linalg.norm(tangent, axis=1) < 1e-6
    tangent[weak] = np.cross(normal[weak], np.eye(3)[np.argmin(np.abs(normal[weak]), axis=1)])
    tangent = normalize(tangent, 0.0)
    tilt = np.radians(rng.uniform(-tilt_deg, tilt_deg, count))
    return normalize(np.cos(tilt)[:, None] * tangent + np.sin(tilt)[:, None] * normal, 0.0)


def _half_tan(fov_deg: float) -> float:
    """tan(fov / 2) of a field of view in degrees, which must lie in (0, 180)."""
    if not 0 < fov_deg < 180:
        raise VDNIFError(f"field of view must be between 0 and 180 degrees, got {fov_deg}")
    return float(np.tan(np.radians(fov_deg) / 2))


def _bounds(bounds_lo: Float[np.ndarray, "3"], bounds_hi: Float[np.ndarray, "3"]
            ) -> tuple[Float[np.ndarray, "3"], Float[np.ndarray, "3"], Float[np.ndarray, "3"],
                       float]:
    """lo (3,), hi (3,), centre (3,) and radius (half the diagonal) of a box; raises for an
    inverted or zero-size box."""
    lo, hi = np.asarray(bounds_lo, dtype=np.float64), np.asarray(bounds_hi, dtype=np.float64)
    radius = np.linalg.norm(hi - lo) / 2
    if not (np.all(hi >= lo) and np.isfinite(radius) and radius > 0):
        raise VDNIFError(f"invalid bounds {lo.tolist()} .. {hi.tolist()}: need lo <= hi and "
                         "a nonzero extent")
    return lo, hi, (lo + hi) / 2, radius


def _uniform_sphere(count: int, rng: np.random.Generator) -> Float[np.ndarray, "count 3"]:
    """(count, 3) unit vectors uniform on the sphere (uniform z and azimuth: Archimedes)."""
    return _sphere_points(rng.uniform(-1.0, 1.0, count), rng.uniform(0.0, 2 * np.pi, count))


def _sphere_points(z: Float[np.ndarray, " N"], azimuth: Float[np.ndarray, " N"]
                   ) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit vectors from heights z (N,) in [-1, 1] and azimuths (N,)."""
    ring = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    return np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=1)
