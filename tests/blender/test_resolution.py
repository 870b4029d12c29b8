"""The suggested resolution (``--resolution auto``): the knee of the measured embedding-error
curve (the coarsest candidate within a margin of the best), raised for thin parts, held to
a target it says it misses; the table's figures are the references measured directly."""

import math

import numpy as np
import pytest

CANDIDATES = (8, 12, 16, 24, 32, 48, 64, 96, 128)


def curve(errors, mismatch=None):
    """A table of rows as ``suggest_resolution`` measures them."""
    mismatch = mismatch or [0.0] * len(errors)
    return [{"resolution": r, "embedding_error": e, "hit_mismatch": m}
            for r, e, m in zip(CANDIDATES, errors, mismatch)]


@pytest.fixture
def resolution(extension, core):
    return core("blender.resolution")


def test_a_curve_with_a_knee_picks_the_knee_never_the_finest(resolution):
    # Steep down to 32 (each coarser one at least 3x the plateau), then a plateau that
    # wobbles by +-20 % and ends higher at the finest: any margin from 0.4 to 1 finds 32.
    plateau = 4e-4
    wobble = [1.0, 0.8, 1.2, 0.9, 1.2]
    errors = [2e-2, 8e-3, 3e-3, 1.3e-3] + [plateau * w for w in wobble]
    for margin in (0.4, 0.5, 1.0):
        assert resolution.knee(curve(errors), margin)["resolution"] == 32
    # A dip below the plateau at a coarse candidate (the arm's 24) is the best: chosen.
    dipped = errors[:3] + [1.5e-4] + errors[4:]
    assert resolution.knee(curve(dipped), 0.5)["resolution"] == 24


def test_a_flat_curve_picks_the_coarsest(resolution):
    rng = np.random.default_rng(0)
    flat = list(3e-4 * (1 + 0.05 * rng.standard_normal(len(CANDIDATES))))
    assert resolution.knee(curve(flat), 0.5)["resolution"] == 8
    # Differences under the absolute tolerance are noise, even where relatively large.
    tiny = [4e-7, 3e-7, 2e-7, 1e-7, 1e-7, 1e-7, 1e-7, 1e-7, 1e-7]
    assert resolution.knee(curve(tiny), 0.5, {"distance": 1e-6})["resolution"] == 8
    assert resolution.knee(curve(tiny), 0.5)["resolution"] == 24


def test_the_hit_mismatch_must_reach_its_knee_too(resolution):
    flat = [3e-4] * len(CANDIDATES)
    mismatch = [0.05, 0.03, 0.01, 0.004, 0.002, 0.002, 0.002, 0.002, 0.002]
    assert resolution.knee(curve(flat, mismatch), 0.5)["resolution"] == 32
    # A candidate with no measured distance (no hit in either reference) never qualifies.
    missing = [None, None] + flat[2:]
    assert resolution.knee(curve(missing), 0.5)["resolution"] == 16


def test_the_thin_floor_is_the_coarsest_candidate_spanning_two_voxels(resolution):
    size = 3.0
    for thickness in (0.5, 0.2, 0.1, 0.07, 0.05):
        chosen = resolution.thin_floor(thickness, size, CANDIDATES, voxels=2)
        assert thickness / (size / chosen) >= 2                     # it spans two voxels
        coarser = [r for r in CANDIDATES if r < chosen]
        assert not coarser or thickness / (size / coarser[-1]) < 2  # the next coarser not
    assert resolution.thin_floor(0.01, size, CANDIDATES) == 128      # none: the finest
    assert resolution.thin_floor(math.inf, size, CANDIDATES) == 0    # nothing thin


@pytest.fixture
def arm(empty_scene, core):
    return core("blender.scenes").demo_scene("arm")


def test_the_suggestion_is_the_knee_of_the_measured_curve(arm, core):
    resolution = core("blender.resolution")
    settings = core("settings")
    spec = core("blender.poses").PoseSpec(count=2)
    candidates = (8, 16)
    suggestion = resolution.suggest_resolution(arm, spec, None, candidates, poses=1, size=24)
    table = suggestion.table
    assert [row["resolution"] for row in table] == [8, 16]
    # The table's figures are reference_run's embedding errors at each resolution, on the
    # development poses (a choice).
    poses = core("blender.poses")
    capture = core("blender.capture_scene").capture(
        arm, 16, poses.evaluation_spec(spec, 1, pose_set="development"), deform_corners=False)
    direct = core("posed.generate").reference_run(arm, capture, 24, 24)["embedded_vs_true"]
    assert table[1]["embedding_error"] == pytest.approx(direct["distance_mae"])
    assert table[1]["hit_mismatch"] == pytest.approx(1 - direct["hit_iou"])
    assert suggestion.target == settings.EMBEDDING_TARGET             # object units
    assert suggestion.knee == resolution.knee(table, tolerance=settings.KNEE_TOLERANCE)
    assert suggestion.resolution == max(suggestion.knee["resolution"],
                                        suggestion.floor.thin)
    # A target nothing meets is said, and changes nothing of the choice.
    strict = resolution.suggest_resolution(arm, spec, 1e-12, candidates, poses=1, size=24)
    assert strict.resolution == suggestion.resolution and strict.none_met
    assert "no candidate meets" in strict.describe()
    loose = resolution.suggest_resolution(arm, spec, 1.0, candidates, poses=1, size=24)
    assert loose.met and "meets it" in loose.describe()


def slab(core, thickness):
    """A 1 x 1 x ``thickness`` box mesh bent by the procedural lattice."""
    import bpy

    bpy.ops.mesh.primitive_cube_add(size=1.0)
    obj = bpy.context.active_object
    obj.scale = (1.0, 1.0, thickness)
    bpy.ops.object.transform_apply(scale=True)
    return core("blender.scenes").add_rig(obj, "lattice")


def test_a_thin_part_raises_the_resolution(empty_scene, core):
    resolution = core("blender.resolution")
    spec = core("blender.poses").PoseSpec(count=1)
    candidates = (8, 12, 16)
    thick = resolution.suggest_resolution(slab(core, 0.5), spec, None, candidates, poses=1,
                                          size=24)
    assert thick.floor.thin == 8 and thick.floor.thickness == pytest.approx(0.5, rel=1e-3)
    # 0.15 thick needs 2 / 0.15 = 13.3 voxels along the side: 16; the measured knee is
    # raised to it whatever the curve says.
    thin = resolution.suggest_resolution(slab(core, 0.15), spec, None, candidates, poses=1,
                                         size=24)
    assert thin.floor.thickness == pytest.approx(0.15, rel=1e-3)
    assert thin.floor.thin == 16 and thin.resolution == 16
    if thin.knee["resolution"] < 16:
        assert "raised from the knee" in thin.describe()


@pytest.fixture
def spot(empty_scene, core):
    return core("blender.scenes").demo_scene("spot")


def test_a_textured_mesh_is_never_suggested_coarser_than_the_recipes_textured_resolution(spot,
                                                                                         core):
    build_parser, RECIPE = core("cli").build_parser, core("settings").RECIPE
    load_posed_scene = core("cli.options").load_posed_scene

    kinds = {albedo.kind for albedo in core("blender.read_mesh").read_rest_mesh(spot).albedo}
    assert "texture" in kinds and RECIPE.textured_resolution > RECIPE.resolution
    assert core("blender.resolution").recipe_resolution(spot) == RECIPE.textured_resolution
    # A scene command without --resolution suggests one (test_a_suggested_resolution_...);
    # a given one stays. (The command builds the scene again: ``spot`` is gone after it.)
    for command in ("capture", "dataset", "references", "train"):
        args = build_parser().parse_args([command, "--scene", "spot"]
                                         + (["--out", "d"] if command == "dataset" else []))
        assert args.resolution == core("settings").AUTO_RESOLUTION, command
    # ``recipe`` is the recipe's, which the paper's experiments train at.
    name = spot.name
    args = build_parser().parse_args(["capture", "--scene", "spot", "--resolution", "recipe"])
    spot = load_posed_scene(args)[0]
    assert spot.name == name and args.resolution == RECIPE.textured_resolution
    args = build_parser().parse_args(["capture", "--scene", "spot", "--resolution", "24"])
    spot = load_posed_scene(args)[0]
    assert args.resolution == 24
    # The suggestion never goes below it: candidates under it are not even tried.
    spec = core("blender.poses").PoseSpec(count=1)
    suggestion = core("blender.resolution").suggest_resolution(spot, spec, 1.0, (8, 16),
                                                               poses=1, size=24)
    assert suggestion.resolution == 16 and [row["resolution"] for row in suggestion.table] == [16]


def test_an_untextured_mesh_has_the_recipes_resolution_and_a_floor_holds(arm, core):
    build_parser, RECIPE = core("cli").build_parser, core("settings").RECIPE
    load_posed_scene = core("cli.options").load_posed_scene

    assert core("blender.resolution").recipe_resolution(arm) == RECIPE.resolution
    # A model command's resolution is the model's unless given (test_cli_models).
    args = build_parser().parse_args(["evaluate", "--scene", "arm", "--model", "m.vdnif"])
    assert args.resolution is None
    arm = load_posed_scene(args)[0]                      # the scene built again
    assert args.resolution is None
    args = build_parser().parse_args(["capture", "--scene", "arm", "--resolution", "recipe"])
    arm = load_posed_scene(args)[0]
    assert args.resolution == RECIPE.resolution
    # A given floor holds: nothing under it is tried.
    spec = core("blender.poses").PoseSpec(count=1)
    suggest = core("blender.resolution").suggest_resolution
    suggestion = suggest(arm, spec, 1.0, (8, 12, 16), poses=1, size=24, floor=12)
    assert [row["resolution"] for row in suggestion.table] == [12, 16]
    assert suggestion.resolution >= 12


def test_a_suggested_resolution_is_recorded_with_its_curve(arm, core, monkeypatch):
    """``--resolution auto`` keeps why it chose: the command's JSON holds the suggestion's
    curve, knee, floor and target (strict JSON), and a given resolution adds nothing."""
    import json

    build_parser, options = core("cli").build_parser, core("cli.options")
    resolution = core("blender.resolution")
    suggest = resolution.suggest_resolution
    monkeypatch.setattr(resolution, "suggest_resolution", lambda obj, spec: suggest(
        obj, spec, None, (8, 16), poses=1, size=24))
    args = build_parser().parse_args(["references", "--scene", "arm", "--resolution", "auto"])
    options.load_posed_scene(args)
    recorded = options.with_suggestion(args, {"object": "Arm"})["resolution_suggestion"]
    assert args.resolution == recorded["resolution"] in (8, 16)
    assert [row["resolution"] for row in recorded["table"]] == [8, 16]
    assert all(row["embedding_error"] > 0 for row in recorded["table"])
    assert recorded["knee"] in (8, 16) and recorded["target"] == core("settings").EMBEDDING_TARGET
    assert json.loads(json.dumps(recorded, allow_nan=False)) == recorded
    given = build_parser().parse_args(["references", "--scene", "arm", "--resolution", "16"])
    options.load_posed_scene(given)
    assert options.with_suggestion(given, {"object": "Arm"}) == {"object": "Arm"}


def test_the_procedural_lattice_holds_every_corner_of_a_flat_mesh(empty_scene, core):
    """Blender holds a lattice's deformation constant outside its box: a lattice as thin as a
    flat mesh leaves the voxel corners above and below it unbent, and the embedding of a
    bent plate then never converges. Along the thin axis every corner of the coarsest and
    a fine grid lies inside the procedural lattice (along the others, 5 % past the mesh,
    from 32 voxels on), and the embedding error falls as the grid refines."""
    import bpy

    bpy.ops.mesh.primitive_cube_add(size=1.0)
    obj = bpy.context.active_object
    obj.scale = (1.0, 1.0, 0.02)
    bpy.ops.object.transform_apply(scale=True)
    # Faces small enough to bend with the lattice (it moves vertices only).
    subdivide = obj.modifiers.new("Subdivide", "SUBSURF")
    subdivide.subdivision_type, subdivide.levels = "SIMPLE", 4
    bpy.ops.object.modifier_apply(modifier=subdivide.name)
    core("blender.scenes").add_rig(obj, "lattice")
    lattice = next(o for o in bpy.data.objects if o.type == "LATTICE")
    half = np.abs(np.array([p.co for p in lattice.data.points])).max(0) * np.array(
        lattice.scale)
    mesh = core("blender.read_mesh").read_rest_mesh(obj)
    for resolution in (8, 64):
        grid = core("geometry.voxels").build_grid(mesh.vertices, mesh.triangles, resolution)
        reach = np.abs(grid.corner_positions() - np.array(lattice.location)).max(0)
        inside = reach <= half
        assert inside[2] and (resolution < 32 or inside.all()), (resolution, reach, half)
    spec = core("blender.poses").PoseSpec(count=2)
    table = core("blender.resolution").suggest_resolution(
        obj, spec, None, (16, 64), poses=2, size=48, floor=0).table
    coarse, fine = (row["embedding_error"] for row in table)
    # Held constant outside a lattice as thin as the slab, the corners gave 0.021 at both.
    assert fine < 0.8 * coarse and fine < 0.01 * 0.02, table
