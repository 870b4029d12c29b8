"""Stability suite without Blender: degenerate meshes, encoder inputs at and beyond the unit
cube, and reduced precision, each against an independent reference (object scale and
extreme poses, in Blender scenes, are in ``test_stability_scenes.py``)."""

import math

import numpy as np
import pytest
import torch

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import voxels
from vdnif_addon.geometry.attributes import FALLBACK_NORMAL, normalize
from vdnif_addon.geometry.restmesh import Albedo, RestMesh
from vdnif_addon.inference.metrics import compare
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.model.encoding import HashGrid
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import NetworkConfig
from vdnif_addon.tracing import groundtruth, references

# --- Degenerate meshes: voxels + walk + ground truth against brute force -----------------

def rest_mesh(vertices, triangles):
    """A one-material RestMesh with flat (face-normal) shading."""
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles, np.int32)
    corners = vertices[triangles]
    face = normalize(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                     FALLBACK_NORMAL)
    return RestMesh(name="stress", vertices=vertices, triangles=triangles,
                    corner_normals=np.repeat(face[:, None], 3, axis=1).astype(np.float32),
                    material_index=np.zeros(len(triangles), np.int32),
                    albedo=[Albedo("constant", np.full(3, 0.5, np.float32))])


def uv_sphere(rings=6, sides=8):
    """A closed sphere: (V, 3) vertices and (T, 3) triangles."""
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([np.outer(np.sin(theta), np.cos(phi)), np.outer(np.sin(theta), np.sin(phi)),
                     np.repeat(np.cos(theta)[:, None], sides, 1)], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([ring, [[0, 0, 1], [0, 0, -1]]]) * [1.0, 0.8, 0.6]
    top, bottom = len(ring), len(ring) + 1
    s = np.arange(sides)
    triangles = [np.stack([np.full(sides, top), s, (s + 1) % sides], 1),
                 np.stack([np.full(sides, bottom), (rings - 2) * sides + (s + 1) % sides,
                           (rings - 2) * sides + s], 1)]
    for r in range(rings - 2):
        a, b = r * sides + s, r * sides + (s + 1) % sides
        triangles += [np.stack([a, a + sides, b], 1), np.stack([b, a + sides, b + sides], 1)]
    return vertices, np.concatenate(triangles)


def rays_at(vertices, count=300, seed=0):
    """Rays from a far sphere aimed at random points of the vertices' bounding box."""
    rng = np.random.default_rng(seed)
    lo, hi = vertices.min(0), vertices.max(0)
    aims = rng.uniform(lo, hi, (count, 3))
    origins = rng.normal(size=(count, 3))
    origins = (lo + hi) / 2 + 3 * np.ptp(vertices, 0).max() * normalize(origins, FALLBACK_NORMAL)
    return origins, normalize(aims - origins, FALLBACK_NORMAL)


def embedded_at_rest(mesh, origins, directions, resolution=8):
    """The embedded reference of the undeformed grid (walk + segment ground truth)."""
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, resolution)
    passes, segments, targets = references.embedded_passes(
        DeviceCells(grid), mesh, groundtruth.rest_surface(mesh, grid), origins, directions)
    assert segments.truncated == 0
    for array in (segments.p0, segments.p1, targets.distance, targets.normal, passes.distance,
                  passes.normal):
        assert np.isfinite(array).all()
    return grid, passes


def brute_force(mesh, origins, directions):
    """Rays cast straight at the triangles, no voxels."""
    return references.true_reference(mesh, groundtruth.rest_surface(mesh), origins,
                                     directions)


def assert_same_passes(embedded, truth, size):
    assert truth.hit.sum() > 30 and (~truth.hit).sum() > 30, "rays should hit and miss"
    assert (embedded.hit != truth.hit).mean() <= 0.01     # grazing an edge may go either way
    both = embedded.hit & truth.hit
    np.testing.assert_allclose(embedded.distance[both], truth.distance[both], atol=1e-9 * size)
    assert compare(embedded, truth, size)["normal_error_deg"] < 0.5


def test_zero_area_triangles_are_harmless():
    vertices, triangles = uv_sphere()
    clean = rest_mesh(vertices, triangles)
    # a collinear triangle (an edge's midpoint added), a repeated corner, a point
    midpoint = len(vertices)
    vertices = np.concatenate([vertices, [(vertices[0] + vertices[1]) / 2]])
    extra = [[0, midpoint, 1], [2, 2, 5], [7, 7, 7]]
    mesh = rest_mesh(vertices, np.concatenate([triangles, extra]))
    assert np.isfinite(mesh.corner_normals).all()
    origins, directions = rays_at(clean.vertices)
    _, embedded = embedded_at_rest(mesh, origins, directions)
    assert_same_passes(embedded, brute_force(clean, origins, directions), 2.0)


def test_duplicate_and_unused_vertices_change_nothing():
    vertices, triangles = uv_sphere()
    welded = rest_mesh(vertices, triangles)
    soup = vertices[triangles].reshape(-1, 3)                   # every corner its own vertex
    stray = np.concatenate([soup, [[50.0, 50.0, 50.0]]])        # used by no triangle
    mesh = rest_mesh(stray, np.arange(len(soup)).reshape(-1, 3))
    origins, directions = rays_at(vertices)
    grid, embedded = embedded_at_rest(mesh, origins, directions)
    welded_grid, _ = embedded_at_rest(welded, origins[:1], directions[:1])
    np.testing.assert_array_equal(grid.cells, welded_grid.cells)
    assert grid.voxel_size == welded_grid.voxel_size
    assert_same_passes(embedded, brute_force(welded, origins, directions), 2.0)


def test_non_manifold_edge_of_three_fins():
    """Three fins share one edge (a non-manifold edge); open, two-sided surfaces."""
    a, b = np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 0.5])
    vertices, triangles = [a, b], []
    for angle in (0.3, 2.4, 4.1):
        out = 0.8 * np.array([math.cos(angle), math.sin(angle), 0.0])
        base = len(vertices)
        vertices += [b + out, a + out]
        triangles += [[0, 1, base], [0, base, base + 1]]
    mesh = rest_mesh(vertices, triangles)
    origins, directions = rays_at(mesh.vertices)
    _, embedded = embedded_at_rest(mesh, origins, directions)
    assert_same_passes(embedded, brute_force(mesh, origins, directions), 1.0)


def test_single_triangle_against_the_plane():
    """A lone triangle in the plane z = 0.2 (a flat grid two cells thick): rays from above
    hit it where the analytic ray-plane point lies inside the triangle."""
    corners = np.array([[0.0, 0.0, 0.2], [1.0, 0.1, 0.2], [0.3, 0.9, 0.2]])
    mesh = rest_mesh(corners, [[0, 1, 2]])
    rng = np.random.default_rng(4)
    aims = np.column_stack([rng.uniform(-0.2, 1.2, (400, 2)), np.full(400, 0.2)])
    origins = aims + normalize(np.column_stack([rng.normal(0, 0.3, (400, 2)), np.ones(400)]),
                               FALLBACK_NORMAL) * 2.0
    directions = normalize(aims - origins, FALLBACK_NORMAL)
    grid, embedded = embedded_at_rest(mesh, origins, directions)
    assert grid.dims[2] == 2
    # analytic: barycentric coordinates of the aim point in the triangle's plane
    e1, e2 = corners[1, :2] - corners[0, :2], corners[2, :2] - corners[0, :2]
    uv = np.linalg.solve(np.column_stack([e1, e2]), (aims[:, :2] - corners[0, :2]).T).T
    inside = (uv >= 0).all(1) & (uv.sum(1) <= 1)
    margin = np.minimum(uv.min(1), 1 - uv.sum(1))
    clear = np.abs(margin) > 1e-6                 # not grazing an edge
    np.testing.assert_array_equal(embedded.hit[clear], inside[clear])
    np.testing.assert_allclose(embedded.distance[inside],
                               np.linalg.norm(aims - origins, axis=1)[inside], atol=1e-12)
    np.testing.assert_allclose(np.abs(embedded.normal[inside, 2]), 1.0, atol=1e-12)


def test_a_mesh_without_area_walks_to_misses():
    """Only degenerate triangles: the core voxelizes them (segments occupy cells), walks and
    finds nothing to hit (a scene with such a mesh is refused: test_stability_scenes.py)."""
    line = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [0.5, 0.5, 0.5]])
    mesh = rest_mesh(line, [[0, 1, 2], [3, 3, 1]])
    origins, directions = rays_at(line)
    _, embedded = embedded_at_rest(mesh, origins, directions)
    assert not embedded.hit.any()


# --- Encoder inputs at and beyond [0, 1] -------------------------------------------------

@pytest.fixture
def dense_grid():
    """Two dense levels (4 and 8 cells per axis) with random features."""
    torch.manual_seed(0)
    grid = HashGrid(levels=2, base_resolution=4, growth=2.0, log2_table_size=12, feature_dim=2)
    with torch.no_grad():
        grid.table.normal_()
    return grid


def vertex_features(grid, ijk_fraction):
    """Reference: the table rows of lattice vertex ``ijk_fraction * res`` at every level."""
    rows = []
    for level, res in enumerate(grid.resolutions):
        x, y, z = (round(c * res) for c in ijk_fraction)
        rows.append(grid.table[grid.level_offsets[level] + x + y * (res + 1)
                               + z * (res + 1) ** 2])
    return torch.cat(rows)


def test_encoder_clamps_inputs_at_and_beyond_the_unit_cube(dense_grid):
    """Exactly 0 and 1 read the first and last lattice vertex; anything outside reads the
    nearest point of the cube (clamped), with finite features and table gradients (the
    encoder has no gradient with respect to positions: they are data, not parameters)."""
    cube = torch.tensor([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    expected = torch.stack([vertex_features(dense_grid, c.tolist()) for c in cube])
    torch.testing.assert_close(dense_grid(cube), expected, rtol=0, atol=1e-6)
    outward = 2 * cube - 1                          # away from the cube at every corner
    for step in (1e-6, 0.5):
        torch.testing.assert_close(dense_grid(cube + step * outward), expected, rtol=0, atol=1e-6)
    mixed = torch.tensor([[-0.5, 0.3, 1.5], [0.3, -1e-6, 1 + 1e-6]])
    torch.testing.assert_close(dense_grid(mixed),
                               dense_grid(torch.tensor([[0.0, 0.3, 1.0], [0.3, 0.0, 1.0]])))
    # training: an outside point sends its gradient to the features of its clamped point
    gradients = []
    for points in (torch.cat([cube + 1e-6 * outward, cube + 0.5 * outward, mixed]),
                   torch.cat([cube, cube, torch.tensor([[0.0, 0.3, 1.0], [0.3, 0.0, 1.0]])])):
        dense_grid.table.grad = None
        (dense_grid(points) ** 2).sum().backward()
        gradients.append(dense_grid.table.grad)
    assert torch.isfinite(gradients[0]).all() and gradients[0].abs().sum() > 0
    torch.testing.assert_close(gradients[0], gradients[1])


def test_network_outputs_stay_finite_at_the_cube_faces_and_outside():
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(width=16, depth=1, log2_table_size=12))
    edge = torch.tensor([0.0, 1.0, -1e-6, 1 + 1e-6, -0.5, 1.5])
    p0 = torch.cartesian_prod(edge, edge, edge)
    p1 = p0.flip(0)
    outputs = network(p0, p1)
    loss = sum(value.float().pow(2).sum() for value in outputs.values())
    loss.backward()
    assert all(torch.isfinite(value).all() for value in outputs.values())
    assert all(torch.isfinite(p.grad).all() for p in network.parameters() if p.grad is not None)


# --- Reduced precision -------------------------------------------------------------------

REDUCED = [("cpu", torch.bfloat16),
           pytest.param("cuda", torch.float16, marks=pytest.mark.skipif(
               not torch.cuda.is_available(), reason="needs CUDA"))]


@pytest.mark.parametrize("device, dtype", REDUCED)
def test_autocast_keeps_positions_and_hash_lookup_in_float32(device, dtype):
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(width=32, depth=2, log2_table_size=14)).to(device)
    with torch.no_grad():
        network.encoder.grid.table.normal_()        # features that vary as a trained grid's
    generator = torch.Generator().manual_seed(1)
    p0 = torch.rand(2000, 3, generator=generator)
    p1 = (p0 + 0.02 * torch.randn(2000, 3, generator=generator)).clamp(0, 1)
    p0, p1 = p0.to(device), p1.to(device)
    length = (p1 - p0).norm(dim=1)
    with torch.no_grad():
        features = network.encoder(p0, p1)
        full_distance = network(p0, p1)["distance"]
        full = network.predict(p0, p1, length, 0.03)
        with torch.autocast(device, dtype=dtype):
            reduced_features = network.encoder(p0, p1)
            reduced_distance = network(p0, p1)["distance"]
            reduced = network.predict(p0, p1, length, 0.03)
        rounded = network.encoder(p0.to(dtype).float(), p1.to(dtype).float())
    # autocast is active: the MLP runs reduced; the heads' activations come out float32
    assert reduced_distance.dtype == torch.float32
    assert not torch.equal(reduced_distance, full_distance)
    # the lookup is float32; under bfloat16 its features come rounded as the first layer
    # rounds them (torch's conversion), under float16 in float32
    handed_on = features.to(torch.bfloat16) if dtype == torch.bfloat16 else features
    assert reduced_features.dtype == handed_on.dtype
    assert torch.equal(reduced_features, handed_on)
    # what the guard avoids: positions rounded to the reduced type change the features
    assert (rounded - features).abs().max() > 0.1
    torch.testing.assert_close(reduced["hit_probability"].float(), full["hit_probability"],
                               rtol=0, atol=0.01)
    torch.testing.assert_close(reduced["distance"].float(), full["distance"],
                               rtol=0.02, atol=1e-4)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_reduced_precision_positions_are_refused(dtype):
    network = IntersectionNetwork(NetworkConfig(width=16, depth=1, log2_table_size=12))
    p = torch.rand(8, 3)
    with pytest.raises(VDNIFError, match=f"segment end points are {dtype}: positions must be"):
        network.predict(p.to(dtype), p.to(dtype), torch.ones(8), 0.03)
    with pytest.raises(VDNIFError, match=f"hash grid points are {dtype}"):
        network.encoder.grid(p.to(dtype))
    assert network.encoder(p.double(), p.double()).dtype == torch.float32
