"""The neural renderer's wave logic, driven by an oracle network that knows the ground truth:
its passes must equal the embedded reference exactly (no bpy needed)."""

import numpy as np
import torch

from vdnif_addon import groundtruth, images, rays, references, render, traverse, voxels
from vdnif_addon.metrics import Passes
from vdnif_addon.restmesh import Albedo, RestMesh


def icosphere_mesh():
    """An octahedron subdivided twice and pushed onto the unit sphere, two materials."""
    vertices = [np.array(v, float) for v in
                ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))]
    faces = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5),
             (0, 3, 5)]
    for _ in range(2):
        midpoints, refined = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in midpoints:
                midpoints[key] = len(vertices)
                vertices.append((vertices[a] + vertices[b]) / 2)
            return midpoints[key]

        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            refined += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
        faces = refined
    v = np.array(vertices)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    triangles = np.array(faces, np.int32)
    normals = v[triangles].astype(np.float32)
    material = (v[triangles].mean(1)[:, 2] > 0).astype(np.int32)
    albedo = [Albedo("constant", np.array(c, np.float32)) for c in ((1, 0, 0), (0, 0, 1))]
    return RestMesh(name="Ball", vertices=v, triangles=triangles, corner_normals=normals,
                    material_index=material, albedo=albedo)


class OracleNetwork:
    """Answers every segment with its exact rest-space ground truth."""

    def __init__(self, mesh, grid):
        self.mesh, self.grid = mesh, grid
        self.caster = groundtruth.rest_surface(mesh)           # segments in no given cell
        self.queries = 0

    def predict(self, p0, p1, rest_len, voxel_size):
        to_rest = lambda p: p.double().numpy() * self.grid.extent + self.grid.origin  # noqa
        segments = traverse.Segments(ray=np.arange(len(p0)), cell=np.zeros(len(p0), int),
                                     t0=np.zeros(len(p0)), t1=np.ones(len(p0)),
                                     p0=to_rest(p0), p1=to_rest(p1))
        hits = groundtruth.segment_targets(self.mesh, self.caster, segments)
        self.queries += len(p0)
        length = rest_len.double().numpy()
        return {"hit": torch.as_tensor(hits.hit),
                "fraction": torch.as_tensor(hits.distance / np.maximum(length, 1e-30)),
                "normal": torch.as_tensor(hits.normal),
                "material": torch.as_tensor(hits.material.astype(np.int64))}


def test_oracle_network_renders_the_embedded_reference():
    mesh = icosphere_mesh()
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, 10)
    bend = grid.corner_positions().copy()
    bend[:, 0] += 0.15 * bend[:, 2] ** 2                        # a smooth non-affine pose
    cells = traverse.DeformedCells.build(grid, bend)
    entry = traverse.BruteForceCaster(cells.boundary_triangles())
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.3, -1, 0.2]) /
                                          np.linalg.norm([0.3, -1, 0.2]), 24, 20)
    oracle = OracleNetwork(mesh, grid)
    predicted, stats = render.neural_passes(oracle, grid, mesh.albedo_table(), cells, entry,
                                            origins, directions)
    rest_caster = groundtruth.rest_surface(mesh, grid)
    reference, segments, _ = references.embedded_passes(cells, entry, mesh, rest_caster,
                                                        origins, directions)
    np.testing.assert_array_equal(predicted.hit, reference.hit)
    assert predicted.hit.sum() > 50
    # the network sees float32 end points: agreement to float32 precision
    np.testing.assert_allclose(predicted.distance, reference.distance, atol=1e-5)
    np.testing.assert_allclose(predicted.normal, reference.normal, atol=1e-5)
    np.testing.assert_array_equal(predicted.material, reference.material)
    np.testing.assert_allclose(predicted.albedo, mesh.albedo_table()[reference.material]
                               * reference.hit[:, None])
    # a ray costs as many queries as cells it crosses up to its hit, not its whole walk
    hit_ray = reference.hit[segments.ray]
    before_or_at_hit = ~hit_ray | (segments.t0 <= reference.distance[segments.ray])
    assert oracle.queries == stats["segments"] == before_or_at_hit.sum() < len(segments)


def test_display_images_and_figure():
    passes = Passes.empty(6)
    passes.hit[:3] = True
    passes.distance[:3] = [1.0, 2.0, 3.0]
    passes.normal[:3] = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]
    shown = images.display(passes, 2, 3, (1.0, 3.0))
    assert shown["normal"].shape == (2, 3, 3)
    np.testing.assert_allclose(shown["normal"][0, 2], [0.5, 0.5, 0.0])
    assert shown["distance"][0, 0, 0] > shown["distance"][0, 2, 0]          # near is bright
    np.testing.assert_allclose(shown["albedo"][1, 0], images.MISS_COLOR)    # a miss
    data = images.raw(passes, 2, 3)
    assert np.isnan(data["distance"][1]).all() and data["distance"][0, 1, 0] == 2.0
    other = Passes.empty(6)
    other.hit[:2] = True
    other.distance[:2] = [1.5, 2.0]
    other.normal[:2] = [[0, 1, 0], [0, 1, 0]]
    errors = images.error_images(passes, other, 2, 3, object_size=1.0, distance_scale=0.5)
    np.testing.assert_allclose(errors["distance"][0, 0], images.heat(np.array(0.5), 0.5))
    np.testing.assert_allclose(errors["normal"][0, 1], images.heat(np.array(0.0), 45))
    np.testing.assert_allclose(errors["distance"][0, 2], 1.0)                # only one hits
    figure = images.comparison_figure([[shown["normal"]] * 3, [shown["distance"]] * 3], gap=1)
    assert figure.shape == (5, 11, 3) and (figure[2] == 1).all()
