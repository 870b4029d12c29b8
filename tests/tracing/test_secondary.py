"""Secondary rays: the training rays that start on the surface, the walk of a ray that starts
inside a cell, and the ambient-occlusion and shadow passes of the exact, embedded and neural
paths on a box standing on a plane, where both are known in closed form (no bpy)."""

import dataclasses

import numpy as np
import pytest
from oracle_network import OracleNetwork
from oracles import walk_past
from oracles.geometry import BruteForceCaster

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import voxels
from vdnif_addon.geometry.attributes import sample_surface
from vdnif_addon.geometry.restmesh import Albedo, RestMesh
from vdnif_addon.inference import neural_render, secondary
from vdnif_addon.inference.evaluation import compare_secondary_both
from vdnif_addon.inference.metrics import compare_secondary
from vdnif_addon.inference.neural_render import neural_passes
from vdnif_addon.kernels.cast import MeshCaster
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.passes import Passes, SecondaryPasses
from vdnif_addon.settings import SECONDARY_OFFSET, SECONDARY_OFFSET_VOXELS, SECONDARY_SELF_REACH
from vdnif_addon.tracing import groundtruth, rays, references

PLANE, BOX, HEIGHT = 2.0, 0.5, 1.0      # plane [-2, 2]^2 at z = 0; box [-.5, .5]^2 x [0, 1]


def box_on_plane():
    """A flat-shaded ground plane with an open-bottomed box standing on it (size 4)."""
    quads = [[(-PLANE, -PLANE, 0), (PLANE, -PLANE, 0), (PLANE, PLANE, 0), (-PLANE, PLANE, 0)]]
    b, h = BOX, HEIGHT
    quads += [[(-b, -b, h), (b, -b, h), (b, b, h), (-b, b, h)],          # top
              [(b, -b, 0), (b, b, 0), (b, b, h), (b, -b, h)],            # +x
              [(-b, b, 0), (-b, -b, 0), (-b, -b, h), (-b, b, h)],        # -x
              [(b, b, 0), (-b, b, 0), (-b, b, h), (b, b, h)],            # +y
              [(-b, -b, 0), (b, -b, 0), (b, -b, h), (-b, -b, h)]]        # -y
    vertices, triangles = [], []
    for quad in quads:
        base = len(vertices)
        vertices += quad
        triangles += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    vertices, triangles = np.array(vertices, float), np.array(triangles, np.int32)
    corners = vertices[triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return RestMesh(name="BoxOnPlane", vertices=vertices, triangles=triangles,
                    corner_normals=np.repeat(normal[:, None], 3, 1).astype(np.float32),
                    material_index=np.zeros(len(triangles), np.int32),
                    albedo=[Albedo("constant", np.array([0.8, 0.8, 0.8], np.float32))])


@pytest.fixture(scope="module")
def scene():
    mesh = box_on_plane()
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 16)
    return mesh, grid, DeviceCells(grid, corners=grid.corner_positions())


def occluders(mesh, grid, cells):
    """Every path's occlusion of one scene at rest: brute force, Warp BVH, embedded, neural
    (an oracle network that answers each segment from the geometry)."""
    return {"brute": secondary.exact_occluded(BruteForceCaster(mesh.vertices[mesh.triangles])),
            "exact": secondary.exact_occluded(MeshCaster(mesh.vertices, mesh.triangles)),
            "embedded": secondary.embedded_occluded(cells, mesh,
                                                    groundtruth.rest_surface(mesh, grid)),
            "neural": secondary.neural_occluded(
                OracleNetwork(mesh, grid), grid, mesh.albedo_table(), cells,
                secondary.network_offset(mesh.size, grid.voxel_size))}


def ground_hits(points):
    """Primary Passes of rays straight down onto ``points`` (N, 3) of the plane from 3 above."""
    count = len(points)
    origins = points + [0.0, 0.0, 3.0]
    directions = np.tile([0.0, 0.0, -1.0], (count, 1))
    passes = Passes(hit=np.ones(count, bool), distance=np.full(count, 3.0),
                    normal=np.tile([0.0, 0.0, 1.0], (count, 1)),
                    albedo=np.zeros((count, 3), np.float32), material=np.zeros(count, np.int32))
    return passes, origins, directions


# --------------------------------------------------------------------------- training rays

def test_secondary_training_rays_leave_the_surface_cosine_weighted():
    """Each starts ``offset`` along the normal of its surface point (SECONDARY_BACK_SHARE of
    them on the back), leaves into that side's hemisphere, and cos(theta)^2 is uniform, as
    the density cos(theta) / pi makes it."""
    rng = np.random.default_rng(21)
    surface = rng.random((50, 3))
    normals = rng.normal(size=(50, 3)) * rng.uniform(0.1, 3.0, (50, 1))     # any length
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    offset = 0.01
    origins, directions = rays.training_rays(np.zeros(3), np.ones(3), surface, 20000, 0.2,
                                             rng, normals, 0.1, secondary_fraction=0.6,
                                             offset=offset)
    # the point and the side each origin starts from: offset from a surface point
    gap = origins[:, None] - surface[None]
    along = np.einsum("rsi,si->rs", gap, unit)
    across = np.linalg.norm(gap - along[..., None] * unit[None], axis=2)
    starts = (across < 1e-12) & np.isclose(np.abs(along), offset, rtol=1e-9, atol=0)
    started = starts.any(axis=1)
    assert started.sum() == 12000
    point = starts.argmax(axis=1)[started]
    side = np.sign(along[started, point])
    assert abs((side < 0).mean() - rays.SECONDARY_BACK_SHARE) < 0.02
    cosine = np.einsum("ni,ni->n", directions[started], side[:, None] * unit[point])
    assert cosine.min() >= 0
    squared = np.sort(cosine ** 2)
    ks = np.abs(squared - (np.arange(len(squared)) + 0.5) / len(squared)).max()
    assert ks < 1.63 / np.sqrt(len(squared))              # Kolmogorov-Smirnov at 1 %
    assert cosine.mean() == pytest.approx(2 / 3, abs=0.01)   # E[cos] under cos / pi


def test_cosine_directions_are_uniform_in_azimuth_about_any_normal():
    rng = np.random.default_rng(3)
    for normal in ([0, 0, 1], [0, 0, -1], [1, 0, 0], [0.3, -0.8, 0.1]):
        normal = np.array(normal, float) / np.linalg.norm(normal)
        d = rays.cosine_directions(np.tile(normal, (20000, 1)), rng.random((20000, 2)))
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
        np.testing.assert_allclose(d.mean(0), 2 / 3 * normal, atol=0.015)   # no azimuth bias


def test_secondary_training_rays_need_normals_and_a_valid_share():
    args = (np.zeros(3), np.ones(3), np.zeros((1, 3)), 10, 0.2, np.random.default_rng(0))
    with pytest.raises(VDNIFError, match="surface normal"):
        rays.training_rays(*args, secondary_fraction=0.5)
    with pytest.raises(VDNIFError, match="at most 1"):
        rays.training_rays(*args, np.ones((1, 3)), 0.3, secondary_fraction=0.6)
    with pytest.raises(VDNIFError, match="offset"):
        rays.training_rays(*args, np.ones((1, 3)), secondary_fraction=0.5, offset=-1.0)


@pytest.mark.parametrize("shear", [0.0, 0.4])
def test_walk_from_inside_a_cell_finds_the_brute_force_first_hit(shear):
    """Rays that start on the surface start inside a cell; the walk and the exact segment
    ground truth (the embedded reference) find the first hit brute force finds. An affine
    pose moves the cells exactly as the mesh, so the embedding is exact there too."""
    mesh = box_on_plane()
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 16)
    matrix = np.array([[1.0, 0.0, shear], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    cells = DeviceCells(grid, corners=grid.corner_positions() @ matrix.T)
    posed = mesh.vertices @ matrix.T
    corners = posed[mesh.triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    rng = np.random.default_rng(5)
    points, triangle, _ = sample_surface(posed, mesh.triangles, 3000, rng)
    origins, directions = rays.training_rays(posed.min(0), posed.max(0), points, 3000, 0.0,
                                             rng, normals[triangle], 0.0,
                                             secondary_fraction=1.0,
                                             offset=SECONDARY_OFFSET * mesh.size)
    walked, _, _ = references.embedded_passes(cells, mesh, groundtruth.rest_surface(mesh, grid),
                                              origins, directions)
    index, t = BruteForceCaster(corners).cast(origins, directions, np.full(3000, np.inf))
    hit = index >= 0
    assert 300 < hit.sum() < 2700                  # both outcomes are well represented
    agree = walked.hit == hit
    assert agree.mean() > 0.998                    # a ray along an edge may go either way
    np.testing.assert_allclose(walked.distance[agree & hit], t[agree & hit], atol=1e-5)


# --------------------------------------------------------------------------- AO and shadow

def wall_ao(gap, reach):
    """AO of a plane point ``gap`` from an infinite wall, rays of length ``reach``: a
    cosine-weighted direction projects uniformly onto the unit disk, and it meets the wall
    within ``reach`` when its component towards the wall is at least gap / reach."""
    c = np.clip(gap / reach, 0, 1)
    return 1 - (np.arccos(c) - c * np.sqrt(1 - c * c)) / np.pi


@pytest.mark.parametrize("path", ["brute", "exact", "embedded", "neural"])
def test_ambient_occlusion_and_shadow_of_a_box_on_a_plane(scene, path):
    """AO beside a wall of the box (taller and wider than the AO reach) and away from it, a
    sun's shadow and a point light's, in closed form, on every path."""
    mesh, grid, cells = scene
    occluded = occluders(mesh, grid, cells)[path]
    settings = secondary.SecondarySettings(
        samples=64, distance=0.05, light=secondary.Light(direction=(1.0, 0.0, 1.0), source="t"))
    reach = settings.distance * mesh.size                         # 0.2 local units
    gaps = np.repeat([0.02, 0.06, 0.1, 0.15], 24)                 # from the +x wall
    y = np.tile(np.linspace(-0.2, 0.2, 24), 4)
    wall = np.stack([BOX + gaps, y, np.zeros_like(y)], 1)
    far = np.stack([np.linspace(1.0, 1.8, 20), np.linspace(-1.8, 1.8, 20), np.zeros(20)], 1)
    shade = np.stack([np.linspace(-1.4, -0.6, 20), np.linspace(-0.4, 0.4, 20), np.zeros(20)], 1)
    points = np.concatenate([wall, far, shade])
    result = secondary.secondary_passes(*ground_hits(points), occluded, mesh.size, settings)
    near = result.ao[:len(wall)].reshape(4, 24).mean(1)
    np.testing.assert_allclose(near, wall_ao(np.array([0.02, 0.06, 0.1, 0.15]), reach),
                               atol=0.035)
    # far from the box nothing occludes: any self-hit at the origin would show here
    np.testing.assert_array_equal(result.ao[len(wall):len(wall) + 20], 1.0)
    # the sun at 45 deg over +x: the box shadows x in [-1.5, -0.5] at |y| < 0.5
    assert result.lit[len(wall):len(wall) + 20].all()
    assert not result.lit[-20:].any()
    # a point light beside +x: its side lit, behind the box shadowed
    lamp = secondary.SecondarySettings(samples=1, light=secondary.Light(
        direction=None, position=(3.0, 0.0, 0.5), source="lamp"))
    lit = secondary.secondary_passes(*ground_hits(np.concatenate([far, shade])), occluded,
                                     mesh.size, lamp).lit
    assert lit[:20].all() and not lit[20:].any()


def test_without_the_offset_the_surface_occludes_itself(scene, monkeypatch):
    """The self-hit the offset exists for: rays started on the plane itself hit it."""
    mesh, grid, cells = scene
    points = np.stack([np.linspace(1.0, 1.8, 20), np.linspace(-1.8, 1.8, 20), np.zeros(20)], 1)
    settings = secondary.SecondarySettings(samples=16)
    occluded = occluders(mesh, grid, cells)["exact"]
    monkeypatch.setattr(secondary, "SECONDARY_OFFSET", 0.0)
    assert (secondary.secondary_passes(*ground_hits(points), occluded, mesh.size,
                                       settings).ao < 1).any()


def tilted_hits(points, angle, error):
    """Primary Passes of rays at ``angle`` (radians) from the plane's normal onto ``points``
    (N, 3) of the plane, from 3 away, their distances off by ``error`` (N,) along the ray."""
    count = len(points)
    azimuth = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    directions = np.stack([np.sin(angle) * np.cos(azimuth), np.sin(angle) * np.sin(azimuth),
                           np.full(count, -np.cos(angle))], 1)
    passes = Passes(hit=np.ones(count, bool), distance=3.0 + error,
                    normal=np.tile([0.0, 0.0, 1.0], (count, 1)),
                    albedo=np.zeros((count, 3), np.float32), material=np.zeros(count, np.int32))
    return passes, points - 3.0 * directions, directions


@pytest.mark.parametrize("path", ["brute", "embedded", "neural"])
def test_a_network_hit_off_the_surface_by_its_error_does_not_occlude_itself(scene, path):
    """Plane hits away from the box, seen head-on and at 60 degrees, moved along their rays
    by up to the network offset's tolerance (a point within the offset less the exact hits'
    of the surface along the normal): their rays, started ``network_offset`` off them, never
    meet the plane they left (AO 1, every one lit), on every path. With the exact hits'
    offset, a hit that far below the plane occludes itself on the exact paths; the network
    walks on past the surface it leaves."""
    mesh, grid, cells = scene
    occluded = occluders(mesh, grid, cells)[path]
    offset = secondary.network_offset(mesh.size, grid.voxel_size)
    exact = SECONDARY_OFFSET * mesh.size
    assert offset == pytest.approx(SECONDARY_OFFSET_VOXELS * grid.voxel_size)
    assert offset > 5 * exact
    tolerance = offset - exact
    points = np.stack([np.linspace(1.0, 1.8, 24), np.linspace(-1.8, 1.8, 24), np.zeros(24)], 1)
    settings = secondary.SecondarySettings(
        samples=16, light=secondary.Light(direction=(1.0, 0.0, 1.0), source="t"))
    for angle in (0.0, np.pi / 3):
        error = np.linspace(-0.999, 0.999, 24) * tolerance / np.cos(angle)
        result = secondary.secondary_passes(*tilted_hits(points, angle, error), occluded,
                                            mesh.size, settings, offset)
        np.testing.assert_array_equal(result.ao, 1.0)
        assert result.lit.all()
    below = secondary.secondary_passes(*tilted_hits(points, 0.0, np.full(24, tolerance)),
                                       occluded, mesh.size, settings, exact)
    if path == "neural":
        assert below.ao.mean() > 0.9 and below.lit.all()
    else:
        assert (below.ao < 0.5).all() and not below.lit.any()


def test_the_network_walks_past_the_surface_it_leaves_and_not_past_an_occluder(scene):
    """Network hits on the plane placed 1.05 to 3 offsets below it (seen head-on and at 60
    degrees), so that their rays start under it: under a sun at 45 degrees each shadow ray
    meets the plane it leaves from below within SECONDARY_SELF_REACH offsets, walks past it
    and lights the hit, and the AO rays of the shallower half do the same but for the few
    that graze it beyond that reach; the exact mesh answers the same rays with the plane.
    Hits beside the box's -x wall meet it within that reach: it faces them (normal -x, the
    plane's +z), so it shadows them. And the plane met from below within the reach by rays
    that leave a wall (normal -x) is an occluder to them, not the surface they leave."""
    mesh, grid, cells = scene
    paths = occluders(mesh, grid, cells)
    offset = secondary.network_offset(mesh.size, grid.voxel_size)
    settings = secondary.SecondarySettings(
        samples=16, light=secondary.Light(direction=(1.0, 0.0, 1.0), source="t"))
    points = np.stack([np.linspace(1.0, 1.5, 24), np.linspace(-1.5, 1.5, 24), np.zeros(24)], 1)
    depth = np.linspace(1.05, 3.0, 24) * offset
    assert (3.0 - 1.0) / np.sqrt(0.5) < SECONDARY_SELF_REACH    # the sun's rays meet it within
    for angle in (0.0, np.pi / 3):
        hits = tilted_hits(points, angle, depth / np.cos(angle))
        network = secondary.secondary_passes(*hits, paths["neural"], mesh.size, settings,
                                             offset)
        assert network.lit.all()
        assert network.ao[depth <= 1.5 * offset].mean() > 0.95
        exact = secondary.secondary_passes(*hits, paths["brute"], mesh.size, settings, offset)
        assert not exact.lit.any() and (exact.ao < 0.2).all()
    gap = np.linspace(1.5, 2.5, 12) * offset
    beside = np.stack([-BOX - gap, np.linspace(-0.4, 0.4, 12), np.zeros(12)], 1)
    lit = secondary.secondary_passes(*ground_hits(beside), paths["neural"], mesh.size,
                                     settings, offset).lit
    assert not lit.any()
    under, up = points - [0.0, 0.0, 0.5 * offset], np.tile([0.0, 0.0, 1.0], (24, 1))
    reach = np.full(24, 2 * offset)
    assert not paths["neural"](under, up, reach, up).any()
    assert paths["neural"](under, up, reach, np.tile([-1.0, 0.0, 0.0], (24, 1))).all()


def test_walking_past_within_the_render_answers_as_a_render_per_skip(scene, monkeypatch):
    """The network's rays that meet the surface they left from below start again within the
    render's waves (``neural_render.WalkPast``): one render, and the same AO and shadow as the
    loop of renders it replaced (``oracles/walk_past.py``), for hits 0.5 to 3.5 offsets below
    the plane seen head-on and at 60 degrees (walked past: the loop takes a render more),
    hits beside the box's wall (an occluder, not walked past: one render), and a bent camera
    view's hits with their cells."""
    mesh, grid, cells = scene
    network = OracleNetwork(mesh, grid)
    offset = secondary.network_offset(mesh.size, grid.voxel_size)
    settings = secondary.SecondarySettings(
        samples=16, light=secondary.Light(direction=(1.0, 0.0, 1.0), source="t"))
    points = np.stack([np.linspace(1.0, 1.5, 24), np.linspace(-1.5, 1.5, 24), np.zeros(24)], 1)
    gap = np.linspace(1.5, 2.5, 12) * offset
    beside = np.stack([-BOX - gap, np.linspace(-0.4, 0.4, 12), np.zeros(12)], 1)
    views = [tilted_hits(points, angle, np.linspace(0.5, 3.5, 24) * offset / np.cos(angle))
             for angle in (0.0, np.pi / 3)] + [ground_hits(beside)]
    renders = []
    render = neural_render.neural_passes

    def counted(*args, **kwargs):
        renders.append(len(args[4]))
        return render(*args, **kwargs)

    monkeypatch.setattr(neural_render, "neural_passes", counted)
    monkeypatch.setattr(walk_past, "neural_passes", counted)
    occluded = secondary.neural_occluded(network, grid, mesh.albedo_table(), cells, offset)
    loop = walk_past.neural_occluded(network, grid, mesh.albedo_table(), cells, offset)
    loop_renders = []
    for hits in views:
        renders.clear()
        got = secondary.secondary_passes(*hits, occluded, mesh.size, settings, offset)
        assert len(renders) == 1
        renders.clear()
        expected = secondary.secondary_passes(*hits, loop, mesh.size, settings, offset)
        loop_renders.append(len(renders))
        for name in ("ao", "lit", "facing"):
            np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
    assert min(loop_renders[:2]) >= 2 and loop_renders[2] == 1      # walked past; not
    bend = grid.corner_positions()
    bend[:, 0] += 0.05 * bend[:, 2] ** 2
    bent = DeviceCells(grid, corners=bend)
    origins, directions = rays.look_at_rays(np.array([2.5, -3.0, 2.5]), np.zeros(3),
                                            rays.DEFAULT_UP, 50, 24, 18)
    predicted, _ = render(network, grid, mesh.albedo_table(), bent, origins, directions)
    got, expected = (secondary.secondary_passes(
        predicted, origins, directions, answer(network, grid, mesh.albedo_table(), bent, offset),
        mesh.size, settings, offset) for answer in (secondary.neural_occluded,
                                                    walk_past.neural_occluded))
    assert (~got.lit[predicted.hit]).any() and got.ao[predicted.hit].min() < 0.9
    for name in ("ao", "lit", "facing"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))


def test_a_secondary_ray_starts_the_offset_above_the_surface_along_itself():
    """Every start lies ``offset`` above the tangent plane; a ray at least
    SECONDARY_GRAZING_COSINE from grazing starts on its own line (no sideways shift), a
    grazing one at most offset / that cosine along it, the rest along the normal."""
    from vdnif_addon.settings import SECONDARY_GRAZING_COSINE as grazing
    rng = np.random.default_rng(5)
    normals = rng.normal(size=(4000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directions = rays.cosine_directions(normals, rng.random((4000, 2)))
    points, offset = rng.random((4000, 3)), 0.03
    start, along = secondary.leave_surface(points, normals, directions, offset)
    gap = start - points
    np.testing.assert_allclose((gap * normals).sum(1), offset, rtol=1e-9)
    cosine = (normals * directions).sum(1)
    steep = cosine >= grazing
    assert 0 < steep.mean() < 1
    np.testing.assert_allclose(gap[steep], along[steep, None] * directions[steep], atol=1e-12)
    np.testing.assert_allclose(along[~steep], offset / grazing)
    assert (along <= offset / grazing + 1e-12).all()


@pytest.mark.parametrize("path", ["brute", "exact", "neural"])
def test_a_large_offset_does_not_move_the_shadows_edge(scene, path):
    """Plane points half the network offset either side of the edge of the box's shadow
    under a sun at 45 degrees (the edge at x = -1.5, in closed form): shadowed inside, lit
    outside. A push of the start along the normal would move the edge by the offset and
    light the points inside."""
    mesh, grid, cells = scene
    occluded = occluders(mesh, grid, cells)[path]
    offset = secondary.network_offset(mesh.size, grid.voxel_size)
    settings = secondary.SecondarySettings(
        samples=1, light=secondary.Light(direction=(1.0, 0.0, 1.0), source="t"))
    y = np.linspace(-0.4, 0.4, 16)
    inside = np.stack([np.full(16, -1.5 + offset / 2), y, np.zeros(16)], 1)
    outside = np.stack([np.full(16, -1.5 - offset / 2), y, np.zeros(16)], 1)
    lit = secondary.secondary_passes(*ground_hits(np.concatenate([inside, outside])),
                                     occluded, mesh.size, settings, offset).lit
    assert not lit[:16].any() and lit[16:].all()


def test_a_network_offset_follows_its_voxel_and_its_error():
    """The most of the exact hits' offset, a share of a voxel and a multiple of the
    held-out distance error, as settings.py states it."""
    from vdnif_addon import settings
    size, h = 4.0, 0.05
    assert secondary.network_offset(size, h) == settings.SECONDARY_OFFSET_VOXELS * h
    mae = 2 * settings.SECONDARY_OFFSET_VOXELS / settings.SECONDARY_OFFSET_ERRORS
    assert secondary.network_offset(size, h, mae) == pytest.approx(
        settings.SECONDARY_OFFSET_ERRORS * mae * h)
    assert secondary.network_offset(size, 1e-6, mae) == SECONDARY_OFFSET * size


def test_the_neural_path_from_a_camera_matches_the_exact_one(scene):
    """A camera's primary hits by the oracle network and by the exact mesh, each with its
    own secondary rays: the same AO and shadow (the embedding is exact at rest, and the
    oracle's hits are exact, so its rays start as the exact hits' do: only the paths
    differ)."""
    mesh, grid, cells = scene
    paths = occluders(mesh, grid, cells)
    origins, directions = rays.look_at_rays(np.array([2.5, -3.0, 2.5]), np.zeros(3),
                                            rays.DEFAULT_UP, 50, 24, 18)
    predicted, _ = neural_passes(OracleNetwork(mesh, grid), grid, mesh.albedo_table(), cells,
                                 origins, directions)
    true = references.true_reference(mesh, groundtruth.rest_surface(mesh), origins,
                                     directions)
    settings = secondary.SecondarySettings(samples=8, light=secondary.Light(
        direction=(-1.0, 0.5, 1.0), source="t"))
    views = secondary.secondary_views(
        {"predicted": predicted, "true": true, "embedded": true}, origins, directions,
        {"neural": paths["neural"], "exact": paths["exact"], "embedded": paths["embedded"]},
        mesh.size, settings, SECONDARY_OFFSET * mesh.size)   # the oracle's hits are exact
    assert set(views) == {"predicted", "true", "embedded", "predicted_true_hit",
                          "embedded_true_hit"}
    assert true.hit.sum() > 200 and (~views["true"].lit[true.hit]).sum() > 10
    assert views["true"].ao[true.hit].min() < 0.9           # the box's foot is occluded
    for passes in views.values():       # a hit that faces away from the light is not lit
        assert passes.facing[passes.hit].any() and not (passes.lit & ~passes.facing).any()
    metrics = compare_secondary_both(views)
    for name in ("vs_true", "vs_embedded"):
        assert metrics[name]["ao_mae"] < 0.01 and metrics[name]["ao_mae_true_hit"] < 0.01
        assert metrics[name]["shadow_false_lit_rate"] <= 0.02
        assert metrics[name]["shadow_false_shadow_rate"] <= 0.02


def test_the_networks_secondary_rays_start_in_its_hits_cells_to_the_same_passes(scene):
    """A camera's oracle-network hits, bent, with the cells the render placed them in and
    without: each secondary ray is given its hit's cell to start in (the AO rays and the
    shadow rays asked for in one batch), and AO and shadow are the same."""
    mesh, grid, _ = scene
    bend = grid.corner_positions()
    bend[:, 0] += 0.05 * bend[:, 2] ** 2
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.look_at_rays(np.array([2.5, -3.0, 2.5]), np.zeros(3),
                                            rays.DEFAULT_UP, 50, 24, 18)
    network = OracleNetwork(mesh, grid)
    predicted, _ = neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                 directions)
    assert predicted.hit.sum() > 200 and (predicted.cell[predicted.hit] >= 0).all()
    settings = secondary.SecondarySettings(samples=4, light=secondary.Light(
        direction=(-1.0, 0.5, 1.0), source="t"))
    occluded = secondary.neural_occluded(network, grid, mesh.albedo_table(), cells,
                                         secondary.network_offset(mesh.size, grid.voxel_size))
    given = []

    def recorded(origins, directions, max_distance, leaving, start_cells=None):
        given.append(start_cells)
        return occluded(origins, directions, max_distance, leaving, start_cells)

    offset = SECONDARY_OFFSET * mesh.size
    with_cells = secondary.secondary_passes(predicted, origins, directions, recorded,
                                            mesh.size, settings, offset)
    hit_cells = predicted.cell[predicted.hit]
    assert len(given) == 1
    np.testing.assert_array_equal(given[0], np.concatenate([
        np.repeat(hit_cells, settings.samples), hit_cells[with_cells.facing[predicted.hit]]]))
    without = secondary.secondary_passes(dataclasses.replace(predicted, cell=None), origins,
                                         directions, recorded, mesh.size, settings, offset)
    assert len(given) == 2 and given[1] is None
    assert with_cells.ao[predicted.hit].min() < 0.9 and (~with_cells.lit[predicted.hit]).any()
    for name in ("hit", "ao", "lit", "facing"):
        np.testing.assert_array_equal(getattr(with_cells, name), getattr(without, name))


def test_secondary_metrics_count_against_the_reference():
    # rays 0-2 are compared: 0 falsely shadowed (the prediction faces away from the light),
    # 1 agreed, 2 falsely lit (the reference faces away)
    reference = SecondaryPasses(hit=np.array([1, 1, 1, 1, 0], bool),
                                ao=np.array([1.0, 0.5, 0.0, 1.0, 0.0], np.float32),
                                lit=np.array([1, 1, 0, 0, 0], bool),
                                facing=np.array([1, 1, 0, 1, 0], bool))
    predicted = SecondaryPasses(hit=np.array([1, 1, 1, 0, 1], bool),
                                ao=np.array([0.5, 0.5, 0.5, 1.0, 1.0], np.float32),
                                lit=np.array([0, 1, 1, 1, 1], bool),
                                facing=np.array([0, 1, 1, 1, 1], bool))
    result = compare_secondary(predicted, reference, suffix="_x")
    assert result == {"secondary_rays_x": 3, "ao_mae_x": pytest.approx(1 / 3),
                      "shadow_false_lit_rate_x": 1.0, "shadow_false_shadow_rate_x": 0.5,
                      "shadow_false_lit_facing_rate_x": 1.0,
                      "shadow_false_shadow_facing_rate_x": 0.5}
    # the same errors from cast shadows: both sides face the light
    cast = compare_secondary(dataclasses.replace(predicted, facing=np.ones(5, bool)),
                             dataclasses.replace(reference, facing=np.ones(5, bool)))
    assert cast["shadow_false_lit_rate"] == 1.0 and cast["shadow_false_shadow_rate"] == 0.5
    assert cast["shadow_false_lit_facing_rate"] == cast["shadow_false_shadow_facing_rate"] == 0
    empty = compare_secondary(predicted, reference, np.zeros(5, bool))
    assert empty["ao_mae"] is None and empty["shadow_false_lit_rate"] is None


def test_bad_secondary_settings_are_refused():
    with pytest.raises(VDNIFError, match="AO samples"):
        secondary.SecondarySettings(samples=0)
    with pytest.raises(VDNIFError, match="AO distance"):
        secondary.SecondarySettings(distance=-1.0)
    with pytest.raises(VDNIFError, match="zero length"):
        secondary.Light(direction=(0.0, 0.0, 0.0))
    with pytest.raises(VDNIFError, match="not both"):
        secondary.Light(direction=(0.0, 0.0, 1.0), position=(1.0, 2.0, 3.0))
