"""The suggested resolution (``--resolution auto``): the coarsest candidate whose measured
embedding error meets the target, against the references measured directly."""

import pytest


@pytest.fixture
def arm(empty_scene, core):
    return core("blender.scenes").demo_scene("arm")


def test_the_coarsest_resolution_that_meets_the_target_is_suggested(arm, core):
    resolution = core("blender.resolution")
    spec = core("blender.poses").PoseSpec(count=2)
    candidates = (8, 16)
    _, table = resolution.suggest_resolution(arm, spec, 0.0, candidates, poses=1, size=24)
    assert [row["resolution"] for row in table] == [8, 16]
    # The table's figures are reference_run's embedding errors at each resolution.
    capture = core("blender.capture").capture(arm, 16, core("blender.poses").PoseSpec(count=1),
                                              deform_corners=False)
    direct = core("blender.generate").reference_run(arm, capture, 24, 24)
    assert table[1]["embedding_error"] == pytest.approx(
        direct["embedded_vs_true"]["distance_mae"])
    coarse, fine = (row["embedding_error"] for row in table)
    assert fine < coarse                              # finer voxels embed the mesh better
    # A target between the two errors picks 16, one above both picks 8 (and stops there),
    # one below both gives the finest candidate.
    between = (coarse + fine) / 2
    assert resolution.suggest_resolution(arm, spec, between, candidates, 1, 24)[0] == 16
    chosen, tried = resolution.suggest_resolution(arm, spec, coarse * 2, candidates, 1, 24)
    assert chosen == 8 and len(tried) == 1
    assert resolution.suggest_resolution(arm, spec, fine / 2, candidates, 1, 24)[0] == 16


def test_the_target_is_a_share_of_a_presets_measured_error(core):
    presets = core("presets").load_presets()
    resolution = core("blender.resolution")
    assert resolution.network_error("fast") == (
        presets["fast"]["measured"][core("presets").PRESET_ERROR])
