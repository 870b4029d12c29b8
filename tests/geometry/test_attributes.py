"""Surface attributes against hand-computed values and independent references."""

import numpy as np
import pytest
from oracles import geometry as oracle

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry import attributes
from vdnif_addon.geometry.restmesh import Albedo, RestMesh

# Degenerate input must be handled explicitly: any numpy floating-point warning fails a test.
pytestmark = pytest.mark.filterwarnings("error")

# (8, 3) offsets of the cell corners, numbered c = dx + 2 dy + 4 dz, written out by hand.
CUBE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0],
                 [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]], dtype=float)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# --- interpolate ---------------------------------------------------------------------------

def test_interpolate_blends_per_corner_values():
    values = np.array([[[1.0, 10.0], [2.0, 20.0], [4.0, 40.0]]])
    np.testing.assert_allclose(attributes.interpolate(values, np.array([[0.5, 0.25, 0.25]])),
                               [[2.0, 20.0]])


# --- sample_texture --------------------------------------------------------------------------

# 2x2 texture, row 0 at v = 0: values [[1, 2], [3, 5]] in channels scaled by (1, 0.5, 0.25).
TEXTURE_VALUES = np.array([[1.0, 2.0], [3.0, 5.0]])
TEXTURE = (TEXTURE_VALUES[:, :, None] * [1.0, 0.5, 0.25]).astype(np.float32)

# (u, v): expected scalar value per mode (REPEAT, EXTEND, MIRROR, CLIP), worked out by hand
# with texel centres at 0.25 and 0.75 and Blender's bilinear footprint.
TEXTURE_CASES = [
    ((0.25, 0.25), (1, 1, 1, 1)),                 # texel centres
    ((0.75, 0.25), (2, 2, 2, 2)),
    ((0.25, 0.75), (3, 3, 3, 3)),
    ((0.75, 0.75), (5, 5, 5, 5)),
    ((0.5, 0.25), (1.5, 1.5, 1.5, 1.5)),          # between two texels
    ((0.5, 0.5), (2.75, 2.75, 2.75, 2.75)),       # between four texels
    ((0.0, 0.25), (1.5, 1, 1, 0.5)),              # left border: half the footprint outside
    ((1.0, 0.25), (1.5, 2, 2, 1)),                # right border
    ((0.0, 0.0), (2.75, 1, 1, 0.25)),             # corner: three quarters outside
    ((-0.1, 0.25), (1.7, 1, 1, 0.3)),             # just outside: CLIP fades
    ((-0.25, 0.25), (2, 1, 1, 0)),                # texel -1
    ((1.25, 0.25), (1, 2, 2, 0)),                 # texel 2
    ((-0.75, 0.25), (1, 1, 2, 0)),                # texel -2
    ((1.75, 0.25), (2, 2, 1, 0)),                 # texel 3
    ((2.25, 0.25), (1, 2, 1, 0)),                 # texel 4
    ((0.25, 1.25), (1, 3, 3, 0)),                 # row 2
    ((5.3, -3.7), (1.31, 2, 2.19, 0)),            # far outside, fractions 0.1 past a texel
]


@pytest.mark.parametrize("mode_index, mode",
                         list(enumerate(["REPEAT", "EXTEND", "MIRROR", "CLIP"])))
def test_sample_texture_matches_hand_computed_values(mode_index, mode):
    cases = [(uv, expected[mode_index]) for uv, expected in TEXTURE_CASES]
    uv = np.array([uv for uv, _ in cases])
    expected = np.array([value for _, value in cases])[:, None] * [1.0, 0.5, 0.25]
    found = attributes.sample_texture(TEXTURE, uv, mode)
    assert found.dtype == np.float32 and found.shape == (len(cases), 3)
    np.testing.assert_allclose(found, expected, atol=1e-6)


def test_sample_texture_maps_u_to_columns_and_v_to_rows_upwards():
    red, green, blue = np.eye(3)
    yellow, cyan, magenta = [1, 1, 0], [0, 1, 1], [1, 0, 1]
    texture = np.array([[red, green, blue], [yellow, cyan, magenta]], dtype=np.float32)  # 3x2
    uv = np.array([[0.5 / 3, 0.25], [1.5 / 3, 0.75], [2.5 / 3, 0.25],
                   [1 / 3, 0.25], [1 / 3, 0.5], [0.0, 0.25]])
    expected = [red, cyan, blue, (red + green) / 2, [0.5, 0.75, 0.25], (red + blue) / 2]
    np.testing.assert_allclose(attributes.sample_texture(texture, uv, "REPEAT"), expected,
                               atol=1e-6)


def test_sample_texture_rejects_bad_input():
    with pytest.raises(VDNIFError, match="extension"):
        attributes.sample_texture(TEXTURE, np.zeros((1, 2)), "WRAP")
    with pytest.raises(VDNIFError, match="texture"):
        attributes.sample_texture(np.zeros((0, 2, 3)), np.zeros((1, 2)), "REPEAT")


# --- surface_albedo --------------------------------------------------------------------------
# (Barycentric weights and shading normals of hits: tests/kernels/test_surface_kernel.py.)

def square_mesh(**overrides):
    """Unit square at z = 0 as two triangles: 0 = (0,0)(1,0)(1,1), 1 = (0,0)(1,1)(0,1);
    material 0 constant, material 1 the 2x2 test texture, UVs = xy."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    triangles = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    fields = dict(
        name="square", vertices=vertices, triangles=triangles,
        corner_normals=np.tile(np.float32([0, 0, 1]), (2, 3, 1)),
        material_index=np.array([0, 1], dtype=np.int32),
        albedo=[Albedo("constant", np.float32([0.2, 0.4, 0.6])),
                Albedo("texture", np.float32([0.9, 0.9, 0.9]), TEXTURE, "EXTEND")],
        uvs=vertices[triangles][:, :, :2].astype(np.float32))
    fields.update(overrides)
    return RestMesh(**fields)


def test_surface_albedo_by_material():
    mesh = square_mesh()
    # Triangle 1 at (0.25, 0.75): x = w1, y = w1 + w2 -> weights (0.25, 0.25, 0.5).
    albedo, material = attributes.surface_albedo(
        mesh, np.array([0, 1, 0]), np.array([[0.2, 0.3, 0.5], [0.25, 0.25, 0.5], [1, 0, 0]]))
    assert material.dtype == np.int32 and material.tolist() == [0, 1, 0]
    assert albedo.dtype == np.float32
    np.testing.assert_allclose(albedo, [[0.2, 0.4, 0.6], [3, 1.5, 0.75], [0.2, 0.4, 0.6]],
                               atol=1e-6)


def test_texture_without_uvs_uses_the_constant_color():
    albedo, _ = attributes.surface_albedo(square_mesh(uvs=None), np.array([1]),
                                          np.array([[0.25, 0.25, 0.5]]))
    np.testing.assert_allclose(albedo, [[0.9, 0.9, 0.9]], atol=1e-7)


def test_color_attribute_is_interpolated():
    colors = np.float32([[[1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 0, 0]] * 3])
    mesh = square_mesh(albedo=[Albedo("attribute", np.float32([0.5, 0.5, 0.5]))],
                       material_index=np.zeros(2, dtype=np.int32), corner_colors=colors)
    albedo, material = attributes.surface_albedo(mesh, np.array([0, 1]),
                                                 np.array([[0.2, 0.3, 0.5], [1, 0, 0]]))
    assert albedo.dtype == np.float32 and material.tolist() == [0, 0]
    np.testing.assert_allclose(albedo, [[0.2, 0.3, 0.5], [0, 0, 0]], atol=1e-7)


def test_single_constant_material_fills_every_point():
    mesh = square_mesh(albedo=[Albedo("constant", np.float32([0.2, 0.4, 0.6]))],
                       material_index=np.zeros(2, dtype=np.int32))
    albedo, material = attributes.surface_albedo(mesh, np.array([0, 1, 1]), np.eye(3))
    np.testing.assert_array_equal(albedo, np.tile(np.float32([0.2, 0.4, 0.6]), (3, 1)))
    assert material.tolist() == [0, 0, 0]
    albedo, material = attributes.surface_albedo(mesh, np.zeros(0, int), np.zeros((0, 3)))
    assert albedo.shape == (0, 3) and material.shape == (0,)


def test_material_index_out_of_range_is_reported():
    mesh = square_mesh(material_index=np.array([0, 2], dtype=np.int32))
    with pytest.raises(VDNIFError, match="material index"):
        attributes.surface_albedo(mesh, np.array([1]), np.array([[1.0, 0, 0]]))


# --- trilinear map, Jacobian and deformed normals --------------------------------------------

def test_trilinear_map_interpolates_the_corners():
    rng = np.random.default_rng(2)
    cells = CUBE + rng.normal(scale=0.2, size=(10, 8, 3))
    for c in range(8):
        local = np.tile(CUBE[c], (10, 1))
        np.testing.assert_allclose(oracle.trilinear_map(cells, local), cells[:, c])
    np.testing.assert_allclose(oracle.trilinear_map(cells, np.full((10, 3), 0.5)),
                               cells.mean(axis=1))


def test_trilinear_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    cells = CUBE + rng.normal(scale=0.3, size=(200, 8, 3))
    local = rng.random((200, 3))
    step = 1e-4
    # The map is linear along each u_j, so central differences are exact up to rounding.
    columns = [(oracle.trilinear_map(cells, local + step * e)
                - oracle.trilinear_map(cells, local - step * e)) / (2 * step)
               for e in np.eye(3)]
    np.testing.assert_allclose(oracle.trilinear_jacobian(cells, local),
                               np.stack(columns, axis=2), atol=1e-9)


def random_affine_cells(rng, count):
    matrices = rng.normal(size=(count, 3, 3))
    offsets = rng.normal(size=(count, 3))
    return matrices, np.einsum("nij,cj->nci", matrices, CUBE) + offsets[:, None]


def test_affine_cells_have_constant_jacobian():
    rng = np.random.default_rng(4)
    matrices, cells = random_affine_cells(rng, 50)
    local = rng.random((50, 3))
    np.testing.assert_allclose(oracle.trilinear_jacobian(cells, local), matrices, atol=1e-12)


def test_deformed_normals_of_affine_maps():
    rng = np.random.default_rng(5)
    matrices, cells = random_affine_cells(rng, 300)     # about half have det < 0
    assert (np.linalg.det(matrices) < 0).any()
    normals = unit(rng.normal(size=(300, 3)))
    jacobian = oracle.trilinear_jacobian(cells, rng.random((300, 3)))
    deformed = oracle.deformed_normals(normals, jacobian)
    expected = unit(np.einsum("nji,nj->ni", np.linalg.inv(matrices), normals))
    np.testing.assert_allclose(deformed, expected, atol=1e-8)
    tangents = np.cross(normals, rng.normal(size=(300, 3)))
    mapped = np.einsum("nij,nj->ni", matrices, tangents)
    np.testing.assert_allclose(np.einsum("ni,ni->n", deformed, mapped), 0, atol=1e-8)
    for factor in (1e-200, 1e200):      # a uniform scale changes nothing, even at the extremes
        np.testing.assert_allclose(oracle.deformed_normals(normals, factor * jacobian),
                                   deformed, atol=1e-12)


def test_deformed_normals_of_singular_jacobians_are_finite_unit_vectors():
    normals = unit(np.array([[0, 0, 1], [1, 2, 3], [1, 1, 1], [1, 0, 0], [1, 1, 1]], dtype=float))
    jacobians = np.array([
        np.zeros((3, 3)),                                   # rank 0: rest normal
        np.outer([1, 2, 3], [0, 1, 1]),                     # rank 1: rest normal
        np.diag([1.0, 1.0, 0.0]),                           # rank 2: flattened along z
        np.diag([1.0, 1.0, 0.0]),                           # n in the cofactor's null space
        np.diag([1e-300, 1.0, 1.0]),                        # nearly singular, tiny entry
    ])
    deformed = oracle.deformed_normals(normals, jacobians)
    assert np.all(np.isfinite(deformed))
    np.testing.assert_allclose(np.linalg.norm(deformed, axis=1), 1.0)
    np.testing.assert_allclose(deformed[:2], normals[:2])
    np.testing.assert_allclose(deformed[2], [0, 0, 1])      # a flattened surface faces z
    np.testing.assert_allclose(deformed[3], normals[3])
    np.testing.assert_allclose(deformed[4], [1, 0, 0], atol=1e-12)     # J^-T blows up x


# --- sample_surface --------------------------------------------------------------------------

def test_sample_surface_is_area_weighted_and_on_the_triangles():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],        # area 0.5
                         [2, 0, 0], [5, 0, 0], [2, 1, 0],        # area 1.5
                         [0, 0, 0], [1, 1, 0], [2, 2, 0]], dtype=float)   # area 0
    triangles = np.arange(9).reshape(3, 3)
    points, triangle, weights = attributes.sample_surface(vertices, triangles, 40000,
                                                          np.random.default_rng(6))
    assert points.shape == (40000, 3) and weights.shape == (40000, 3)
    counts = np.bincount(triangle, minlength=3)
    assert counts[2] == 0
    assert counts[1] / counts[0] == pytest.approx(3.0, abs=0.15)
    # On the triangle: in its plane and on the inner side of each edge (2-D edge functions).
    corners = vertices[triangles[triangle]]
    np.testing.assert_allclose(points[:, 2], 0.0)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        edge = corners[:, b, :2] - corners[:, a, :2]
        to_point = points[:, :2] - corners[:, a, :2]
        assert np.all(edge[:, 0] * to_point[:, 1] - edge[:, 1] * to_point[:, 0] >= -1e-12)
    # Uniform within a triangle: the samples' mean is its centroid.
    np.testing.assert_allclose(points[triangle == 1].mean(axis=0), [3, 1 / 3, 0], atol=0.02)


def test_sample_surface_of_zero_area_mesh_raises():
    vertices = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2]], dtype=float)
    with pytest.raises(VDNIFError, match="zero"):
        attributes.sample_surface(vertices, np.array([[0, 1, 2]]), 10, np.random.default_rng(0))
