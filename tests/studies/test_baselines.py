"""The classical baselines of side-by-side: on the same posed mesh they hit what each other
and the true reference hit; Warp's BVH bytes agree with what Warp itself counts (Embree's:
tests/studies/test_baselines_embree.py); and the extension never imports embreex, a benchmark
dependency."""

import ast
import importlib
import re
import subprocess
import sys

import numpy as np
import pytest
from conftest import ENABLE_IN_FRESH_PROCESS, EXTENSION_MODULE, REPO
from test_side_by_side import lattice_capture

# Rays through an edge or a vertex that float32 triangle tests of different libraries may
# give to neither neighbour: at most this many per view may differ between two casters.
EDGE_RAYS = 2
DISTANCE_TOLERANCE = 1e-5          # object units: float32 distances of a few object sizes


def core(name):
    return importlib.import_module(f"{EXTENSION_MODULE}.vdnif_addon.{name}")


@pytest.fixture(scope="module")
def posed_casts(extension):
    """Every baseline and the true reference on one unseen pose of the lattice demo's
    Suzanne, three 32x32 orbit views: {name: (hit, distance)} and the object size."""
    poses = core("blender.poses")
    rays = core("tracing.rays")
    obj, captured = lattice_capture(1)
    mesh = captured.mesh
    made = core("studies.baselines")
    baselines, embree = made.make_baselines(mesh, threads=2)
    try:
        with poses.posed(captured.poses[0]):
            for baseline in baselines:
                baseline.rebuild(obj)
            vertices, normals = core("blender.read_mesh").evaluated_surface(obj, mesh)
        true = core("kernels.surface").SurfaceCaster(vertices, mesh.triangles, normals)
        views = [rays.orbit_rays(vertices.min(0), vertices.max(0), view, 32, 32)
                 for view in rays.orbit_viewpoints(3)]
        casts = {baseline.name: [(index >= 0, t) for index, t in
                                 (baseline.cast(*view) for view in views)]
                 for baseline in baselines}
    finally:
        made.close_baselines(baselines, embree)
    reference = core("tracing.references").true_reference
    casts["true"] = [(passes.hit, np.where(passes.hit, passes.distance, np.inf))
                     for passes in (reference(mesh, true, *view) for view in views)]
    return casts, mesh.size


@pytest.mark.parametrize("first, second", [
    ("bvhtree", "warp"), ("bvhtree", "embree_refit"), ("warp", "embree_rebuild"),
    ("embree_refit", "embree_rebuild"), ("bvhtree", "true"), ("warp", "true"),
    ("embree_refit", "true"), ("embree_rebuild", "true")])
def test_baselines_hit_the_same_rays_at_the_same_distances(posed_casts, first, second):
    casts, size = posed_casts
    for (hit_a, distance_a), (hit_b, distance_b) in zip(casts[first], casts[second]):
        assert hit_a.sum() > 100                              # the view sees the mesh
        assert (hit_a != hit_b).sum() <= EDGE_RAYS
        both = hit_a & hit_b
        np.testing.assert_allclose(distance_a[both] / size, distance_b[both] / size,
                                   rtol=0, atol=DISTANCE_TOLERANCE)
        assert np.isinf(distance_a[~hit_a]).all()


def _grid_mesh(rows):
    """A wavy height field of 2 rows^2 triangles: vertices (V, 3), triangles (T, 3)."""
    x, y = np.meshgrid(np.linspace(0, 1, rows + 1), np.linspace(0, 1, rows + 1))
    vertices = np.stack([x, y, 0.1 * np.sin(7 * x) * np.cos(5 * y)], -1).reshape(-1, 3)
    corner = (np.arange(rows)[:, None] * (rows + 1) + np.arange(rows)[None, :]).ravel()
    triangles = np.concatenate([np.stack([corner, corner + 1, corner + rows + 2], 1),
                                np.stack([corner, corner + rows + 2, corner + rows + 1], 1)])
    return vertices, triangles.astype(np.int32)


def test_warp_bvh_bytes_match_warps_own_allocation_tracker(extension):
    """Warp's tracker lists every live native allocation of a new mesh: its bounds
    ('native:mesh') and its BVH ('native:bvh'), besides two small structs."""
    import warp as wp

    baselines = core("studies.baselines")
    core("kernels.runtime").init()
    units = {"B": 1, "KB": 1024, "MB": 1024 ** 2}
    for rows in (30, 90):
        vertices, triangles = _grid_mesh(rows)
        points = wp.array(vertices.astype(np.float32), dtype=wp.vec3, device="cpu")
        indices = wp.array(triangles.ravel(), dtype=wp.int32, device="cpu")
        report = []
        with wp.ScopedMemoryTracker("mesh", report_func=report.append):
            mesh = wp.Mesh(points=points, indices=indices)
        listed = [float(size) * units[unit] for size, unit in re.findall(
            r"([\d.]+) (B|KB|MB) : cpu : \(native:(?:bvh|mesh)\)", report[0])]
        assert mesh.id and len(listed) == 8                  # 6 arrays and 2 structs
        arrays = sum(size for size in listed if size > 1024)
        expected = baselines.warp_bvh_bytes(len(triangles))
        assert abs(arrays - expected) <= 0.005 * expected    # the report rounds to 0.01 KB


def test_the_extension_never_imports_embreex():
    """In a fresh process the enabled extension and every module of it import no embreex;
    in the sources only the benchmark's baselines import it, inside functions."""
    script = ENABLE_IN_FRESH_PROCESS + f"""
import importlib, pkgutil
assert addon_utils.check("{EXTENSION_MODULE}")[1], "not enabled"
extension = sys.modules["{EXTENSION_MODULE}"]
count = 0
for package in ("vdnif_addon", "operators", "panels"):
    module = importlib.import_module(f"{EXTENSION_MODULE}.{{package}}")
    for info in pkgutil.walk_packages(module.__path__, module.__name__ + "."):
        if not info.name.endswith(".batch"):
            importlib.import_module(info.name)
            count += 1
print("modules:", count, "embreex imported:", "embreex" in sys.modules)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)
    found = re.search(r"modules: (\d+) embreex imported: (\w+)", done.stdout)
    assert found, done.stdout + done.stderr
    assert int(found.group(1)) > 40 and found.group(2) == "False"
    importers = {}
    for path in REPO.rglob("*.py"):
        if {".venv", "tests", "tools"} & set(path.relative_to(REPO).parts):
            continue
        tree = ast.parse(path.read_text())
        top_level = {id(node) for node in tree.body}
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(name.split(".")[0] == "embreex" for name in names):
                importers.setdefault(path.relative_to(REPO).as_posix(), []).append(
                    id(node) in top_level)
    assert set(importers) == {"vdnif_addon/studies/baselines_embree.py"}
    assert not any(importers["vdnif_addon/studies/baselines_embree.py"])  # never at import
