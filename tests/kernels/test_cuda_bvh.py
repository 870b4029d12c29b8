"""Every Warp BVH of the pipeline is built by one constructor on every device (Warp's default
is SAH on the CPU, LBVH on CUDA, whose trees can report another of two triangles a ray meets
at the same distance): checked on the CPU by recording the constructor each ``wp.Mesh`` is
given; that CUDA then reports the CPU's triangles is ``test_surface_kernel``'s CUDA test."""

import warp as wp
from test_render import bent_ball

from vdnif_addon.kernels import runtime
from vdnif_addon.kernels.cast import MeshCaster
from vdnif_addon.tracing import groundtruth


def test_every_mesh_is_built_with_the_same_constructor(monkeypatch):
    made = []
    real = wp.Mesh

    def mesh(*args, **kwargs):
        made.append(kwargs.get("bvh_constructor"))
        return real(*args, **kwargs)

    monkeypatch.setattr(wp, "Mesh", mesh)
    mesh_data, grid, _ = bent_ball()
    MeshCaster(mesh_data.vertices, mesh_data.triangles)
    groundtruth.rest_surface(mesh_data, grid)                 # grouped by cell: built twice
    groundtruth.rest_surface(mesh_data)
    assert made == [runtime.BVH_CONSTRUCTOR] * 4 and runtime.BVH_CONSTRUCTOR == "sah"
