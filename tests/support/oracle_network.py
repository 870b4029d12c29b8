"""A stand-in network that answers every segment with its exact rest-space ground truth, for
the tests of the renderer and of what drives it. It uses the copy of the core its mesh comes
from (``vdnif_addon`` or the extension's), so each test file keeps to one identity of the
core (tests/project/test_module_identity.py)."""

import importlib

import numpy as np
import torch


def core_module(mesh, name):
    """Module ``name`` (``"tracing.groundtruth"``) of the core package that made ``mesh``."""
    package, found, _ = type(mesh).__module__.rpartition(".geometry.")
    assert found, f"{type(mesh).__module__} is not a module of the core's geometry stage"
    return importlib.import_module(f"{package}.{name}")


class OracleNetwork:
    """Answers every segment with its exact rest-space ground truth."""

    def __init__(self, mesh, grid):
        self.mesh, self.grid = mesh, grid
        self.groundtruth = core_module(mesh, "tracing.groundtruth")
        self.walk_rules = core_module(mesh, "geometry.walk_rules")
        self.caster = self.groundtruth.rest_surface(mesh)      # segments in no given cell
        self.queries = 0
        self.precision = "float32"          # exact answers: no arithmetic to lower

    def parameters(self):
        """No weights: it answers on the device its inputs are on."""
        return iter(())

    def predict(self, p0, p1, rest_len, voxel_size):
        to_rest = lambda p: p.double().numpy() * self.grid.extent + self.grid.origin  # noqa: E731
        segments = self.walk_rules.Segments(
            ray=np.arange(len(p0)), cell=np.zeros(len(p0), int), t0=np.zeros(len(p0)),
            t1=np.ones(len(p0)), p0=to_rest(p0), p1=to_rest(p1))
        hits = self.groundtruth.segment_targets(self.mesh, self.caster, segments)
        self.queries += len(p0)
        length = rest_len.double().numpy()
        return {"hit": torch.as_tensor(hits.hit), "candidate": torch.as_tensor(hits.hit),
                "fraction": torch.as_tensor(hits.distance / np.maximum(length, 1e-30)),
                "normal": torch.as_tensor(hits.normal),
                "material": torch.as_tensor(hits.material.astype(np.int64))}


def oracle_scene_model(core, capture):
    """A ``posed.render.SceneModel`` of ``capture`` whose network is the OracleNetwork, on
    the CPU (``core``: the test's ``core`` fixture)."""
    from model_metadata import capture_metadata

    return core("posed.render").SceneModel(
        network=OracleNetwork(capture.mesh, capture.grid),
        metadata=capture_metadata(core, capture), grid=capture.grid, path="oracle",
        device="cpu")
