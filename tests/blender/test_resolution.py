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
    capture = core("blender.capture_scene").capture(
        arm, 16, core("blender.poses").PoseSpec(count=1), deform_corners=False)
    direct = core("posed.generate").reference_run(arm, capture, 24, 24)
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


@pytest.fixture
def spot(empty_scene, core):
    return core("blender.scenes").demo_scene("spot")


def test_a_textured_mesh_trains_at_the_recipes_textured_resolution(spot, core):
    build_parser, RECIPE = core("cli").build_parser, core("settings").RECIPE
    load_posed_scene = core("cli.options").load_posed_scene

    kinds = {albedo.kind for albedo in core("blender.read_mesh").read_rest_mesh(spot).albedo}
    assert "texture" in kinds and RECIPE.textured_resolution > RECIPE.resolution
    assert core("blender.resolution").recipe_resolution(spot) == RECIPE.textured_resolution
    # A command without --resolution takes it once the mesh is read; a given one stays.
    # (The command builds the scene again: ``spot`` is gone after it.)
    name, args = spot.name, build_parser().parse_args(["capture", "--scene", "spot"])
    assert args.resolution is None
    spot = load_posed_scene(args)[0]
    assert spot.name == name
    assert args.resolution == RECIPE.textured_resolution
    args = build_parser().parse_args(["capture", "--scene", "spot", "--resolution", "24"])
    spot = load_posed_scene(args)[0]
    assert args.resolution == 24
    # The suggestion never goes below it: candidates under it are not even tried.
    spec = core("blender.poses").PoseSpec(count=1)
    chosen, tried = core("blender.resolution").suggest_resolution(spot, spec, 1.0, (8, 16),
                                                                  poses=1, size=24)
    assert chosen == 16 and [row["resolution"] for row in tried] == [16]


def test_an_untextured_mesh_trains_at_the_recipes_resolution(arm, core):
    build_parser, RECIPE = core("cli").build_parser, core("settings").RECIPE
    load_posed_scene = core("cli.options").load_posed_scene

    assert core("blender.resolution").recipe_resolution(arm) == RECIPE.resolution
    args = build_parser().parse_args(["capture", "--scene", "arm"])
    arm = load_posed_scene(args)[0]                      # the scene built again
    assert args.resolution == RECIPE.resolution
    # No floor: a target every candidate meets stops at the coarsest; a given floor holds.
    spec = core("blender.poses").PoseSpec(count=1)
    suggest = core("blender.resolution").suggest_resolution
    assert suggest(arm, spec, 1.0, (8, 12, 16), poses=1, size=24)[0] == 8
    assert suggest(arm, spec, 1.0, (8, 12, 16), poses=1, size=24, floor=12)[0] == 12
