"""Camera, orbit, transform and training rays against geometric facts worked out by hand."""

import numpy as np
import pytest

from vdnif_addon.errors import VDNIFError
from vdnif_addon.tracing import rays

pytestmark = pytest.mark.filterwarnings("error")


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_look_at_centre_pixel_aims_at_the_target_and_corners_span_the_fov():
    width, height, fov = 5, 3, 60.0
    eye = np.array([0.0, -5.0, 0.0])
    origins, directions = rays.look_at_rays(eye, [0, 0, 0], [0, 0, 1], fov, width, height)
    assert origins.shape == directions.shape == (15, 3)
    np.testing.assert_allclose(origins, np.tile(eye, (15, 1)))
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    np.testing.assert_allclose(directions[1 * width + 2], [0, 1, 0], atol=1e-12)
    # Camera looks along +y with right = +x and up = +z. Pixel centres sit half a pixel in
    # from the image edges, which lie at tan(fov / 2) horizontally.
    half = np.tan(np.radians(fov / 2))
    top_left, bottom_right = directions[0], directions[-1]
    assert top_left[0] / top_left[1] == pytest.approx(-(1 - 1 / width) * half)
    assert top_left[2] / top_left[1] == pytest.approx((1 - 1 / height) * half * height / width)
    assert bottom_right[0] / bottom_right[1] == pytest.approx((1 - 1 / width) * half)
    assert bottom_right[2] / bottom_right[1] == pytest.approx(-(1 - 1 / height) * half * height
                                                              / width)


def test_look_at_with_up_along_the_view_still_works():
    origins, directions = rays.look_at_rays([0, 0, 5], [0, 0, 0], [0, 0, 1], 40, 3, 3)
    assert np.all(np.isfinite(directions))
    np.testing.assert_allclose(directions[4], [0, 0, -1], atol=1e-12)
    # The image is still a square grid: the four edge-centre pixels are symmetric.
    angles = np.degrees(np.arccos(directions[[1, 3, 5, 7]] @ [0, 0, -1]))
    np.testing.assert_allclose(angles, angles[0])


def test_camera_rays_of_identity_camera_look_down_minus_z():
    origins, directions = rays.camera_rays(np.eye(4), 90, 3, 3)
    np.testing.assert_allclose(origins, 0.0)
    np.testing.assert_allclose(directions[4], [0, 0, -1], atol=1e-12)
    assert directions[0, 0] < 0 and directions[0, 1] > 0     # top-left: -x, +y


def test_camera_rays_match_look_at_for_a_rotated_scaled_camera():
    # Blender camera at (0, -5, 0) with rotation X = 90 degrees looks along +y with +z up.
    matrix = np.array([[1, 0, 0, 0], [0, 0, -1, -5], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)
    matrix[:3, :3] *= 2.5
    camera = rays.camera_rays(matrix, 50, 4, 3)
    look_at = rays.look_at_rays([0, -5, 0], [0, 0, 0], [0, 0, 1], 50, 4, 3)
    np.testing.assert_allclose(camera[0], look_at[0])
    np.testing.assert_allclose(camera[1], look_at[1], atol=1e-12)


def test_bad_camera_input_is_reported():
    with pytest.raises(VDNIFError, match="field of view"):
        rays.look_at_rays([0, 0, 1], [0, 0, 0], [0, 1, 0], 180, 2, 2)
    with pytest.raises(VDNIFError, match="coincides"):
        rays.look_at_rays([0, 0, 0], [0, 0, 0], [0, 1, 0], 40, 2, 2)
    with pytest.raises(VDNIFError, match="image size"):
        rays.camera_rays(np.eye(4), 40, 0, 2)


def test_orbit_viewpoints():
    fixed = rays.orbit_viewpoints(200)
    np.testing.assert_allclose(np.linalg.norm(fixed, axis=1), 1.0)
    np.testing.assert_array_equal(fixed, rays.orbit_viewpoints(200))
    np.testing.assert_allclose(fixed.mean(axis=0), 0.0, atol=0.01)      # evenly spread
    random = rays.orbit_viewpoints(2000, seed=3)
    np.testing.assert_allclose(np.linalg.norm(random, axis=1), 1.0)
    np.testing.assert_array_equal(random, rays.orbit_viewpoints(2000, seed=3))
    assert not np.allclose(random, rays.orbit_viewpoints(2000, seed=4))
    # Uniform on the sphere: every coordinate is uniform in [-1, 1] (Archimedes).
    np.testing.assert_allclose(np.abs(random).mean(axis=0), 0.5, atol=0.03)
    assert rays.orbit_viewpoints(0).shape == (0, 3)


@pytest.mark.parametrize("width, height", [(8, 6), (6, 8)])
def test_orbit_rays_fit_the_bounding_sphere_in_the_view(width, height):
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([3.0, 1.0, 2.5])
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    direction = unit(np.array([1.0, -2.0, 0.5]))
    origins, directions = rays.orbit_rays(lo, hi, direction, width, height, fov_deg=40)
    assert origins.shape == (width * height, 3)
    np.testing.assert_allclose(origins, np.tile(origins[0], (len(origins), 1)))
    eye = origins[0]
    np.testing.assert_allclose(unit(eye - centre), direction)
    # Half angle of the largest cone inside the image: the narrower of the two fields of view.
    half_tan = np.tan(np.radians(20)) * min(1.0, height / width)
    cone = np.arctan(half_tan)
    sphere = centre + radius * unit(np.random.default_rng(7).normal(size=(5000, 3)))
    angles = np.arccos(np.clip(unit(sphere - eye) @ unit(centre - eye), -1, 1))
    assert angles.max() <= cone + 1e-9
    assert np.arcsin(radius / np.linalg.norm(eye - centre)) == pytest.approx(cone)  # tight fit
    # Every pixel ray lies within the image's frustum around the view axis.
    assert np.all(directions @ unit(centre - eye) > 0)


def test_orbit_rays_reject_empty_bounds():
    with pytest.raises(VDNIFError, match="bounds"):
        rays.orbit_rays([1, 1, 1], [1, 1, 1], [0, 0, 1], 4, 4)
    with pytest.raises(VDNIFError, match="bounds"):
        rays.orbit_rays([1, 1, 1], [0, 2, 2], [0, 0, 1], 4, 4)


def test_transform_rays_with_a_scale_matrix():
    matrix = np.diag([2.0, 3.0, 4.0, 1.0])
    matrix[:3, 3] = [1, 1, 1]
    origins = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    directions = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    new_origins, new_directions, scale = rays.transform_rays(origins, directions, matrix)
    np.testing.assert_allclose(new_origins, [[3, 4, 5], [1, 1, 1], [11, 16, 21]])
    np.testing.assert_allclose(new_directions, [[1, 0, 0], [0, 1, 0], [0, 0, 0]])
    np.testing.assert_allclose(scale, [2, 3, 0])


def test_transform_rays_scale_converts_distances():
    rng = np.random.default_rng(8)
    matrix = np.eye(4)
    matrix[:3] = rng.normal(size=(3, 4))
    origins, directions = rng.normal(size=(100, 3)), unit(rng.normal(size=(100, 3)))
    distance = rng.random(100) * 10                  # world distance along each ray
    local_origins, local_directions, scale = rays.transform_rays(origins, directions, matrix)
    world_points = origins + distance[:, None] * directions
    local_points = world_points @ matrix[:3, :3].T + matrix[:3, 3]
    local_distance = np.linalg.norm(local_points - local_origins, axis=1)
    np.testing.assert_allclose(local_distance / scale, distance)
    np.testing.assert_allclose(local_origins + local_distance[:, None] * local_directions,
                               local_points, atol=1e-9)


def distance_to_lines(points, origins, directions):
    """(N, P) distance from every point (P, 3) to every line (N, origin + t direction)."""
    offset = points[None] - origins[:, None]
    along = np.einsum("npi,ni->np", offset, directions)
    return np.linalg.norm(offset - along[..., None] * directions[:, None], axis=2)


def passes_through_box(origins, directions, lo, hi):
    """Slab test: does each ray (forwards) cross the box?"""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origins) / directions, (hi - origins) / directions
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    return (near <= far) & (far >= 0)


def test_training_rays():
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([3.0, 1.0, 2.5])
    centre, radius = (lo + hi) / 2, 1.5 * np.linalg.norm(hi - lo) / 2
    rng = np.random.default_rng(9)
    surface = lo + rng.random((40, 3)) * (hi - lo)
    origins, directions = rays.training_rays(lo, hi, surface, 1000, 0.3, rng)
    assert origins.shape == directions.shape == (1000, 3)
    np.testing.assert_allclose(np.linalg.norm(origins - centre, axis=1), radius)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    assert np.all(passes_through_box(origins, directions, lo, hi))
    through_surface = distance_to_lines(surface, origins, directions).min(axis=1) < 1e-9
    assert through_surface.sum() == 300
    # Origins cover the whole sphere, not a cap.
    np.testing.assert_allclose(unit(origins - centre).mean(axis=0), 0.0, atol=0.1)


def test_training_rays_all_on_the_surface_and_reproducible():
    lo, hi = np.zeros(3), np.ones(3)
    surface = np.array([[0.5, 0.5, 0.5], [0.1, 0.9, 0.2]])
    first = rays.training_rays(lo, hi, surface, 200, 1.0, np.random.default_rng(10))
    second = rays.training_rays(lo, hi, surface, 200, 1.0, np.random.default_rng(10))
    np.testing.assert_array_equal(first[0], second[0])
    assert np.all(distance_to_lines(surface, *first).min(axis=1) < 1e-9)


@pytest.mark.parametrize("fraction", [-0.1, 1.5, float("nan")])
def test_training_rays_reject_a_bad_surface_fraction(fraction):
    with pytest.raises(VDNIFError, match="surface_fraction"):
        rays.training_rays(np.zeros(3), np.ones(3), np.zeros((1, 3)), 10, fraction,
                           np.random.default_rng(0))


def test_training_rays_need_surface_points_for_surface_rays():
    with pytest.raises(VDNIFError, match="surface points"):
        rays.training_rays(np.zeros(3), np.ones(3), np.zeros((0, 3)), 10, 0.5,
                           np.random.default_rng(0))


def test_grazing_training_rays_skim_the_surface_at_sampled_points():
    """Grazing rays pass through a surface point, within the tilt of its tangent plane, from
    outside the origin sphere; the other kinds keep their shares."""
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([3.0, 1.0, 2.5])
    centre, radius = (lo + hi) / 2, 1.5 * np.linalg.norm(hi - lo) / 2
    rng = np.random.default_rng(11)
    surface = lo + rng.random((30, 3)) * (hi - lo)
    normals = rng.normal(size=(30, 3)) * rng.uniform(0.1, 5.0, (30, 1))  # any length
    origins, directions = rays.training_rays(lo, hi, surface, 1000, 0.2, rng, normals, 0.5,
                                             grazing_tilt_deg=10.0)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    sphere = np.isclose(np.linalg.norm(origins - centre, axis=1), radius)
    grazing = ~sphere
    assert grazing.sum() == 500
    assert np.all(np.linalg.norm(origins[grazing] - centre, axis=1) > radius)
    gaps = distance_to_lines(surface, origins[grazing], directions[grazing])
    point = gaps.argmin(axis=1)
    assert np.all(gaps.min(axis=1) < 1e-9)
    # Ahead of the origin, and at 80..90 deg to the normal of the point it passes through.
    assert np.all(np.einsum("ni,ni->n", surface[point] - origins[grazing],
                            directions[grazing]) > 0)
    cosine = np.abs(np.einsum("ni,ni->n", unit(normals[point]), directions[grazing]))
    assert cosine.max() <= np.sin(np.radians(10.0)) + 1e-9
    assert cosine.max() > np.sin(np.radians(8.0))  # the whole tilt range is used
    on_surface = distance_to_lines(surface, origins[sphere], directions[sphere]).min(axis=1)
    assert (on_surface < 1e-9).sum() == 200


def test_training_rays_without_grazing_rays_are_unchanged():
    """A zero grazing share draws exactly the rays of the two-kind mix (same random stream)."""
    lo, hi = np.zeros(3), np.ones(3)
    surface = np.random.default_rng(1).random((20, 3))
    plain = rays.training_rays(lo, hi, surface, 300, 0.6, np.random.default_rng(2))
    mixed = rays.training_rays(lo, hi, surface, 300, 0.6, np.random.default_rng(2),
                               np.ones((20, 3)), 0.0)
    np.testing.assert_array_equal(plain[0], mixed[0])
    np.testing.assert_array_equal(plain[1], mixed[1])


@pytest.mark.parametrize("surface, grazing, normals, message", [
    (0.6, 0.5, np.ones((1, 3)), "at most 1"),
    (0.2, -0.1, np.ones((1, 3)), "grazing_fraction"),
    (0.2, 0.5, None, "surface normal"),
    (0.2, 0.5, np.ones((2, 3)), "surface normal"),
])
def test_training_rays_reject_a_bad_grazing_mix(surface, grazing, normals, message):
    with pytest.raises(VDNIFError, match=message):
        rays.training_rays(np.zeros(3), np.ones(3), np.zeros((1, 3)), 10, surface,
                           np.random.default_rng(0), normals, grazing)
