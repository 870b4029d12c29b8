"""The neural renderer's wave logic, driven by an oracle network that knows the ground truth:
its passes must equal the embedded reference exactly (no bpy needed); and the renderer
against the numpy/torch renderer it replaced (``oracles/render.py``). Its golden passes, in a
Blender scene, are in ``test_render_golden.py``."""

import numpy as np
import pytest
import torch
from oracle_network import OracleNetwork
from oracles import render as old_render
from oracles import walk as old_walk

from vdnif_addon.geometry import voxels
from vdnif_addon.geometry.restmesh import Albedo, RestMesh
from vdnif_addon.inference import images
from vdnif_addon.inference import neural_render as render
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.passes import Passes
from vdnif_addon.tracing import groundtruth, rays, references


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


def bent_ball(resolution=10):
    """The ball, its grid and a smooth non-affine pose of its corners."""
    mesh = icosphere_mesh()
    grid = voxels.build_grid(mesh.vertices, mesh.triangles, resolution)
    bend = grid.corner_positions().copy()
    bend[:, 0] += 0.15 * bend[:, 2] ** 2
    return mesh, grid, bend


def test_oracle_network_renders_the_embedded_reference():
    mesh, grid, bend = bent_ball()
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.3, -1, 0.2]) /
                                          np.linalg.norm([0.3, -1, 0.2]), 24, 20)
    oracle = OracleNetwork(mesh, grid)
    # one segment per ray and wave: a ray is evaluated exactly up to its hit
    predicted, stats = render.neural_passes(oracle, grid, mesh.albedo_table(), cells,
                                            origins, directions, schedule=(1,), wave_floor=0)
    rest_caster = groundtruth.rest_surface(mesh, grid)
    reference, segments, _ = references.embedded_passes(cells, mesh, rest_caster,
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
    # the default waves (k growing) give the same passes; segments past a ray's hit within
    # its last wave are evaluated too, never more than the walk has
    again, more = render.neural_passes(OracleNetwork(mesh, grid), grid, mesh.albedo_table(),
                                       cells, origins, directions)
    for name in ("hit", "distance", "normal", "albedo", "material"):
        np.testing.assert_array_equal(getattr(again, name), getattr(predicted, name))
    assert stats["segments"] <= more["segments"] < len(segments)
    assert more["waves"] < stats["waves"]


def test_the_passes_name_the_cell_of_each_hit():
    """A render's ``cell`` pass holds, for each hit, a cell of its ray's walk whose segment
    holds the hit's distance, and -1 for each miss; a reference walks no cells (None)."""
    mesh, grid, bend = bent_ball()
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.3, -1, 0.2]) /
                                          np.linalg.norm([0.3, -1, 0.2]), 24, 20)
    predicted, _ = render.neural_passes(OracleNetwork(mesh, grid), grid, mesh.albedo_table(),
                                        cells, origins, directions)
    segments = old_walk.traverse(old_walk.DeformedCells(grid, bend), cells, origins,
                                 directions)
    hit = predicted.hit
    assert hit.sum() > 50 and (~hit).sum() > 50
    np.testing.assert_array_equal(predicted.cell[~hit], -1)
    ray = segments.ray
    distance = predicted.distance[ray]
    holds = (hit[ray] & (segments.cell == predicted.cell[ray])
             & (segments.t0 <= distance + 1e-9) & (distance <= segments.t1 + 1e-9))
    assert set(np.flatnonzero(hit)) == set(ray[holds])
    reference = references.true_reference(mesh, groundtruth.rest_surface(mesh), origins,
                                          directions)
    assert reference.cell is None


def test_few_rays_walk_on_in_fewer_waves_to_the_same_passes():
    """Where a wave's rays are so few that it would hold under ``wave_floor`` segments, each
    walks more than the schedule's k: the passes are the same (a ray's passes depend only on
    its own segments in walk order), in fewer waves, and no segment is walked twice."""
    mesh, grid, bend = bent_ball()
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.3, -1, 0.2]) /
                                          np.linalg.norm([0.3, -1, 0.2]), 12, 10)
    renders = {floor: render.neural_passes(OracleNetwork(mesh, grid), grid,
                                           mesh.albedo_table(), cells, origins, directions,
                                           schedule=(1,), wave_floor=floor)
               for floor in (0, 120 * 3, render.WAVE_FLOOR)}
    exact, exact_stats = renders[0]
    assert exact.hit.sum() > 10 and exact_stats["waves"] > 4
    for floor, (passes, stats) in renders.items():
        for name in ("hit", "distance", "normal", "albedo", "material"):
            np.testing.assert_array_equal(getattr(passes, name), getattr(exact, name))
        assert stats["segments"] >= exact_stats["segments"]
    assert renders[120 * 3][1]["waves"] < exact_stats["waves"]
    assert renders[render.WAVE_FLOOR][1]["waves"] == 1


class RandomNetwork:
    """Deterministic pseudo-random answers from the segment's end points (no training
    needed): hits, candidates (the hits and a share of the others), fractions, normals,
    materials and optionally albedo, in integer arithmetic on the quantized end points, so
    that every device gives the same bits."""

    def __init__(self, materials=2, albedo=False):
        self.materials, self.albedo = materials, albedo

    def parameters(self):
        """No weights: it answers on the device its inputs are on."""
        return iter(())

    def predict(self, p0, p1, rest_len, voxel_size):
        q = torch.cat([p0, p1], 1).mul(1 << 20).floor().long()
        primes = torch.tensor([73856093, 19349663, 83492791, 2654435761, 805459861, 3674653429],
                              device=p0.device)
        code = (q * primes).sum(1) % 10007                                   # 0..10006
        unit = (code.double() / 10007.0).float()
        out = {"hit": code % 3 == 0, "candidate": (code % 3 == 0) | (code % 4 == 1),
               "fraction": unit,
               "normal": torch.nn.functional.normalize(torch.stack(
                   [unit - 0.5, ((code % 7) - 3).float(), ((code % 11) - 5).float()], 1), dim=1),
               "material": code % self.materials}
        if self.albedo:
            out["albedo"] = torch.stack([unit, 1 - unit, (code % 5).float() / 4], 1)
        return out


@pytest.mark.parametrize("albedo", [False, True])
def test_renderer_equals_the_old_renderer(albedo):
    """Kernel walk + waves + device resolve against numpy walk + torch + numpy resolve,
    with the same entry BVH, on a bent pose and rays from outside and inside."""
    mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    rng = np.random.default_rng(3)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([-0.5, 0.4, 1]) /
                                          np.linalg.norm([-0.5, 0.4, 1]), 40, 30)
    inside = rng.uniform(bend.min(0), bend.max(0), (300, 3))
    origins = np.concatenate([origins, inside])
    directions = np.concatenate([directions, rng.normal(size=(300, 3))])
    network = RandomNetwork(albedo=albedo)
    table = np.array([[0.2, 0.4, 0.6], [0.9, 0.1, 0.0]], np.float32)
    got, stats = render.neural_passes(network, grid, table, cells, origins, directions)
    expected, old_stats = old_render.neural_passes(
        network, grid, table, old_walk.DeformedCells(grid, bend), cells, origins,
        directions)
    assert expected.hit.sum() > 300 and (~expected.hit).sum() > 300
    np.testing.assert_array_equal(got.hit, expected.hit)
    np.testing.assert_array_equal(got.material, expected.material)
    np.testing.assert_allclose(got.distance, expected.distance, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.normal, expected.normal, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got.albedo, expected.albedo)
    assert stats["truncated"] == old_stats["truncated"] == 0


def test_a_limited_render_finds_the_unlimited_hits_within_its_limit():
    """``max_distance`` ends each ray's walk after the cell that crosses it: the walk is a
    prefix of the unlimited one, so every hit within the limit is the unlimited render's
    (same distance), and a hit beyond it only one the unlimited render has too. Rays from
    outside and from inside the ball (as secondary rays start)."""
    mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    rng = np.random.default_rng(8)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.3, -0.5, 1]) /
                                          np.linalg.norm([0.3, -0.5, 1]), 30, 20)
    inside = rng.uniform(0.8 * bend.min(0), 0.8 * bend.max(0), (400, 3))
    origins = np.concatenate([origins, inside])
    directions = np.concatenate([directions, rng.normal(size=(400, 3))])
    network = OracleNetwork(mesh, grid)
    whole, _ = render.neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                    directions)
    limits = rng.uniform(0.0, 2.0, len(origins))
    cut, _ = render.neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                  directions, max_distance=limits)
    within = whole.hit & (whole.distance <= limits)
    assert within.sum() > 150 and (whole.hit & ~within).sum() > 150
    assert within[600:].sum() > 50                          # from inside, too
    np.testing.assert_array_equal(cut.hit & (cut.distance <= limits), within)
    assert not (cut.hit & ~whole.hit).any()
    np.testing.assert_array_equal(cut.distance[cut.hit], whole.distance[cut.hit])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_renderer_on_cuda_equals_the_cpu():
    """``--device cuda``: the cells, the walk and the resolve on the GPU with the network."""
    mesh, grid, bend = bent_ball(12)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([-0.5, 0.4, 1]) /
                                          np.linalg.norm([-0.5, 0.4, 1]), 40, 30)
    table = np.array([[0.2, 0.4, 0.6], [0.9, 0.1, 0.0]], np.float32)
    network = RandomNetwork(albedo=True)
    cpu, _ = render.neural_passes(network, grid, table, DeviceCells(grid, corners=bend),
                                  origins, directions)
    gpu, stats = render.neural_passes(network, grid, table,
                                      DeviceCells(grid, "cuda:0", corners=bend), origins,
                                      directions, device="cuda")
    assert cpu.hit.sum() > 100 and stats["truncated"] == 0
    np.testing.assert_array_equal(gpu.hit, cpu.hit)
    np.testing.assert_array_equal(gpu.material, cpu.material)
    np.testing.assert_allclose(gpu.distance, cpu.distance, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gpu.normal, cpu.normal, rtol=0, atol=1e-6)
    np.testing.assert_allclose(gpu.albedo, cpu.albedo, rtol=0, atol=1e-6)


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
    data = images.compositor_passes(passes, 2, 3)
    assert (data["Depth"][1] == 1e10).all() and data["Depth"][0, 1, 0] == 2.0
    np.testing.assert_array_equal(data["Combined"][..., 3], passes.hit.reshape(2, 3))
    preview = images.previews(passes, 2, 3, (1.0, 3.0))
    np.testing.assert_array_equal(preview["albedo"][..., 3], passes.hit.reshape(2, 3))
    # the mask in the colour too, for a viewer that drops alpha: white hits, black misses
    for channel in range(4):
        np.testing.assert_array_equal(preview["hit"][..., channel], passes.hit.reshape(2, 3))
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


@pytest.mark.parametrize("size", [(128, 96), (161, 97)])
def test_lanes_walked_at_once_render_what_one_lane_renders(monkeypatch, size):
    """The render walks and resolves its lanes at once, one Warp launch per lane on threads
    of its own (``kernels.launches``), with a network of the trained network's kind: run
    after run, in 2 and 3 lanes, it must give the passes of the same render with every
    launch made alone, bit for bit, and launches must have run at once (else nothing was
    tested). Against one lane only the network's batch differs (the lanes' segments in
    another order), which may round its float32 outputs otherwise: the same hits and
    materials, the rest within a few float32 ulps."""
    import threading
    import time

    import warp as wp

    from vdnif_addon.model.metadata import Thresholds
    from vdnif_addon.model.network import IntersectionNetwork
    from vdnif_addon.settings import Heads, NetworkConfig
    from vdnif_addon.tracing.traverse import traverse

    mesh, grid, bend = bent_ball(16)
    cells = DeviceCells(grid, corners=bend)
    torch.manual_seed(size[0])
    network = IntersectionNetwork(NetworkConfig(
        levels=4, base_resolution=8, log2_table_size=12, width=32, depth=2, pe_bands=2,
        heads=Heads(albedo=True, material_count=2)))
    network.eval()
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.4, -0.3, 1]) /
                                          np.linalg.norm([0.4, -0.3, 1]), *size)
    # thresholds at quantiles of the untrained network's probabilities over the walked
    # segments, so that rays stop at a share of their segments and walk on past the others
    walked = traverse(cells, origins, directions)
    probability = render.predict_segments(network, grid, walked, "cpu")["hit_probability"]
    network.thresholds = Thresholds(*(float(probability.quantile(q)) for q in (0.9, 0.8)))
    launch, alone = wp.launch, threading.Lock()
    spans = []

    def serial(*args, **kwargs):
        with alone:
            return launch(*args, **kwargs)

    def timed(*args, **kwargs):
        start = time.perf_counter()
        try:
            return launch(*args, **kwargs)
        finally:
            spans.append((start, time.perf_counter(), threading.get_ident(), args[0].key))

    def passes_with(wrapper, lanes):
        monkeypatch.setattr(wp, "launch", wrapper)
        try:
            return render.neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                        directions, lanes=lanes, schedule=(1, 2))[0]
        finally:
            monkeypatch.setattr(wp, "launch", launch)

    one_lane = passes_with(serial, 1)
    assert 0.05 * len(origins) < one_lane.hit.sum() < 0.9 * len(origins)
    for lanes in (2, 3):
        expected = passes_with(serial, lanes)
        for name in ("hit", "material"):
            np.testing.assert_array_equal(getattr(expected, name), getattr(one_lane, name))
        for name in ("distance", "normal", "albedo"):
            np.testing.assert_allclose(getattr(expected, name), getattr(one_lane, name),
                                       rtol=1e-6, atol=1e-6, err_msg=name)
        for _ in range(4):
            got = passes_with(timed, lanes)
            for name in ("hit", "distance", "normal", "albedo", "material"):
                np.testing.assert_array_equal(getattr(got, name), getattr(expected, name), name)
    spans.sort()
    assert any(b[0] < a[1] and b[2] != a[2] for a, b in zip(spans, spans[1:])), \
        "no two launches ran at once: nothing was tested"


def test_a_render_in_no_lanes_is_refused():
    from vdnif_addon.errors import VDNIFError

    mesh, grid, bend = bent_ball()
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.0, 0.0, 1.0]),
                                          8, 8)
    with pytest.raises(VDNIFError, match="at least one lane, not 0"):
        render.neural_passes(RandomNetwork(), grid, mesh.albedo_table(), cells, origins,
                             directions, lanes=0)
