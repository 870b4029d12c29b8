"""The neural renderer in a Blender scene: the arm's golden passes rendered again, also with
its lanes' Warp launches at once (``test_render.py`` holds the renderer's tests without
Blender)."""

import pathlib

import numpy as np
from conftest import extension_oracle

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"


def test_renderer_reproduces_its_golden_passes(core):
    """The arm at resolution 12 in its first evaluation pose, rendered with the golden model
    (tests/golden/make_goldens.py), its encoder the torch twin of the kernel, as the golden
    passes were: the oracle encoder keeps this a test of the render kernels alone."""
    golden = np.load(GOLDEN / "arm-render.npz")
    network, metadata = core("model.model_file").load_model(GOLDEN / "arm-render-model.vdnif")
    network.encoder = extension_oracle("encoding_torch").from_product(network.encoder)
    obj = core("blender.scenes").demo_scene("arm")
    spec = core("blender.poses").PoseSpec(count=1)
    grid = core("blender.capture_scene").capture(obj, 12, spec, deform_corners=False).grid
    cells = core("kernels.cells").DeviceCells(grid, corners=golden["corners"])
    table = metadata.albedo_colors()
    passes, stats = core("inference.neural_render").neural_passes(network, grid, table, cells,
                                                 golden["origins"], golden["directions"])
    assert golden["hit"].sum() > 10 and stats["truncated"] == 0
    np.testing.assert_array_equal(passes.hit, golden["hit"])
    np.testing.assert_allclose(passes.distance, golden["distance"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(passes.normal, golden["normal"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(passes.albedo, golden["albedo"], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(passes.material, golden["material"])


def test_lanes_walked_at_once_reproduce_the_golden_passes(core, monkeypatch):
    """The render in two lanes walks and resolves them on two threads at once: Warp launches
    run from two threads at once (``kernels.launches``), and the passes are still the golden
    ones. Each launch is stretched by a millisecond so that launches from the two threads
    meet."""
    import threading
    import time

    import warp as wp

    golden = np.load(GOLDEN / "arm-render.npz")
    network, metadata = core("model.model_file").load_model(GOLDEN / "arm-render-model.vdnif")
    obj = core("blender.scenes").demo_scene("arm")
    grid = core("blender.capture_scene").capture(obj, 12, core("blender.poses").PoseSpec(count=1),
                                           deform_corners=False).grid
    cells = core("kernels.cells").DeviceCells(grid, corners=golden["corners"])
    table = metadata.albedo_colors()
    launch, guard = wp.launch, threading.Lock()
    seen = {"active": 0, "most": 0, "threads": set()}

    def stretched(*args, **kwargs):
        with guard:
            seen["active"] += 1
            seen["most"] = max(seen["most"], seen["active"])
            seen["threads"].add(threading.get_ident())
        try:
            time.sleep(0.001)
            return launch(*args, **kwargs)
        finally:
            with guard:
                seen["active"] -= 1

    monkeypatch.setattr(wp, "launch", stretched)
    render = core("inference.neural_render")
    passes, _ = render.neural_passes(network, grid, table, cells, golden["origins"],
                                     golden["directions"], lanes=2, schedule=(1,))
    assert len(seen["threads"]) >= 2, "the lanes did not run at once: nothing was tested"
    assert seen["most"] == 2
    np.testing.assert_array_equal(passes.hit, golden["hit"])
