"""Secondary rays in the side-by-side study: every path casts as many AO rays as its primary
hits times the samples and at most one shadow ray per hit, at 1 and N samples in one run,
each rate positive and finite; each path's rays are answered by its own occluder (the
network's by the network); Warp's, Embree's and Blender's BVHTree's answers to the same
secondary rays agree (three independent ray casters); where the cheaper side changes is
exact for totals linear in the samples; and the command writes the table."""

import json
import math
import types

import numpy as np
import pytest
from test_side_by_side import RAYS, OracleNetwork, core, stand_in_model

SAMPLES = 4
EDGE_SHARE = 0.01     # secondary rays through an edge or a vertex that casters may split


@pytest.fixture(scope="module")
def timed(extension, tmp_path_factory):
    """compare_paths with secondary rays on the lattice demo's Suzanne at R 8, 2 unseen
    poses, 16x16 rays, one repeat, with the oracle network as the model."""
    side = core("studies.side_by_side")
    poses = core("blender.poses")
    obj = core("studies.side_by_side_scenes").load_side_by_side_scene("lattice")
    captured = core("blender.capture_scene").capture(
        obj, 8, poses.evaluation_spec(poses.PoseSpec(count=2)), deform_corners=False)
    model = stand_in_model(OracleNetwork(captured.mesh, captured.grid), captured,
                           tmp_path_factory.mktemp("model") / "oracle.vdnif")
    settings = core("inference.secondary").SecondarySettings(samples=SAMPLES)
    return side.compare_paths(obj, captured, model, RAYS, RAYS, repeats=1,
                              secondary=settings)


def test_each_path_casts_its_hits_times_the_samples_and_a_shadow_ray_per_lit_face(timed):
    secondary = core("studies.side_by_side_secondary")
    assert timed["speed_withheld"] is None
    records = timed["runs"][0]["poses"]
    assert len(records) == 2
    for name in secondary.SECONDARY_PATHS:       # one of the views sees the lit side
        assert sum(r[secondary.key(name, 1, "shadow_rays")] for r in records) > 20
    for record in records:
        for name in secondary.SECONDARY_PATHS:
            hits = record[f"{name}_hits"]          # counted from the primary hit mask
            assert hits > 20
            for samples in (1, SAMPLES):
                assert record[secondary.key(name, samples, "ao_rays")] == hits * samples
                shadow = record[secondary.key(name, samples, "shadow_rays")]
                assert 0 <= shadow <= hits         # hits facing away need no ray
                assert record[secondary.key(name, samples, "s")] > 0
        # the classical paths have the same hits and the same triangles' normals
        for name in ("embree_refit", "embree_rebuild"):
            assert abs(record[f"{name}_hits"] - record["warp_hits"]) <= 2
            assert abs(record[secondary.key(name, SAMPLES, "shadow_rays")]
                       - record[secondary.key("warp", SAMPLES, "shadow_rays")]) <= 2
    assert "bvhtree_secondary1_s" not in records[0]


def test_each_path_answers_its_secondary_rays_with_its_own_occluder(extension, monkeypatch):
    """Four hits on a plane facing the light: the network says every secondary ray is
    blocked, the classical caster that none is, and each path's AO and lit share say so."""
    secondary = core("studies.side_by_side_secondary")
    passes = core("passes")
    monkeypatch.setattr(secondary, "neural_occluded", lambda *args, **kwargs: (
        lambda origins, directions, reach, leaving: np.ones(len(origins), bool)))
    vertices = np.array([[-10.0, -10.0, 0.0], [10.0, -10.0, 0.0], [0.0, 10.0, 0.0]])
    caster = types.SimpleNamespace(name="warp", vertices=vertices, cast=lambda o, d, reach: (
        np.full(len(o), -1), np.full(len(o), np.inf)))
    origins = np.array([[x, y, 1.0] for x in (-1.0, 1.0) for y in (-1.0, 1.0)])
    directions = np.tile([0.0, 0.0, -1.0], (4, 1))
    predicted = passes.Passes.empty(4)
    predicted.hit[:] = True
    predicted.distance[:] = 1.0
    predicted.normal[:] = (0.0, 0.0, 1.0)
    model = types.SimpleNamespace(network=None, albedo_table=None, device="cpu",
                                  secondary_offset=lambda size: 0.01)
    settings = core("inference.secondary").SecondarySettings(samples=2)
    record = secondary.secondary_record(
        [caster], {"warp": (np.zeros(4, int), np.ones(4))}, model, predicted, None, None,
        np.array([[0, 1, 2]]), (origins, directions), 1.0, settings, lambda: None)
    for samples in (1, 2):
        assert record[secondary.key("warp", samples, "ao_mean")] == 1.0
        assert record[secondary.key("warp", samples, "lit_share")] == 1.0
        assert record[secondary.key("neural", samples, "ao_mean")] == 0.0
        assert record[secondary.key("neural", samples, "lit_share")] == 0.0


def test_rates_and_pose_totals_at_one_and_n_samples(timed):
    secondary = core("studies.side_by_side_secondary")
    table = timed["secondary"]
    assert table["settings"]["samples"] == [1, SAMPLES]
    # The network's hits start their rays off by its own error, as its passes do: at R 8
    # SECONDARY_OFFSET_VOXELS of a voxel at least, above an exact hit's offset.
    voxels = core("settings").SECONDARY_OFFSET_VOXELS
    assert table["settings"]["network_offset"] >= voxels / 8 > table["settings"]["offset"]
    assert set(table["paths"]) == set(secondary.SECONDARY_PATHS)
    assert "bvhtree" in table["skipped"]
    for name, by_samples in table["paths"].items():
        primary = core("studies.side_by_side_plots").pose_total(timed, name)
        for samples in (1, SAMPLES):
            figures = by_samples[str(samples)]
            for what in ("rays", "ms", "rays_per_s", "pose_total_ms"):
                assert math.isfinite(figures[what]) and figures[what] > 0, (name, what)
            assert figures["rays"] == figures["ao_rays"] + figures["shadow_rays"]
            assert figures["rays_per_s"] == pytest.approx(
                figures["rays"] / (figures["ms"] / 1e3))
            assert figures["pose_total_ms"] == pytest.approx(primary + figures["ms"])
            assert 0 <= figures["ao_mean"] <= 1 and 0 <= figures["lit_share"] <= 1
        assert by_samples[str(SAMPLES)]["ao_rays"] == SAMPLES * by_samples["1"]["ao_rays"]
    for row in table["trade"].values():
        assert row["text"].startswith(("neural cheaper", "classical cheaper"))
    text = "\n".join(core("studies.side_by_side_report").side_by_side_markdown([timed]))
    for name in secondary.SECONDARY_PATHS:
        short = core("studies.side_by_side_plots").SHORT[name]
        for samples in (1, SAMPLES):
            assert f"| {short}, {samples} AO sample(s): secondary rays/s" in text
            assert f"| {short}, {samples} AO sample(s): pose total ms" in text
    assert "| where the cheaper side changes: neural / Embree refit |" in text
    assert "- BVHTree (Python loop): not timed with secondary rays" in text


def test_the_trade_point_is_exact_for_totals_linear_in_the_samples(extension):
    secondary = core("studies.side_by_side_secondary")

    def path(at_one, at_n):
        return {"1": {"pose_total_ms": at_one}, "17": {"pose_total_ms": at_n}}

    # neural 10 + 2.5 (s - 1), classical 20 + 1.25 (s - 1): equal at s = 9
    row = secondary.trade_point(path(10.0, 50.0), path(20.0, 40.0), [1, 17])
    assert row["samples"] == pytest.approx(9.0)
    assert row["text"].startswith("neural cheaper up to 9 AO samples")
    row = secondary.trade_point(path(20.0, 40.0), path(10.0, 50.0), [1, 17])
    assert row["samples"] == pytest.approx(9.0) and "from 9 AO" in row["text"]
    # the gap closes by 10 ms over 16 samples from 20 ms: the lines meet at 33, past 17
    row = secondary.trade_point(path(30.0, 60.0), path(10.0, 50.0), [1, 17])
    assert row["samples"] is None and row["text"].startswith("classical cheaper at 1 and 17")
    assert row["beyond"] == pytest.approx(33.0)
    assert row["text"].endswith("the lines meet at 33 AO samples (extrapolated)")
    row = secondary.trade_point(path(30.0, 80.0), path(10.0, 50.0), [1, 17])
    assert row["beyond"] is None and row["text"].endswith("(neural / classical 3 at 1, 1.6 "
                                                          "at 17)")
    row = secondary.trade_point(path(None, None), path(10.0, 50.0), [1, 17])
    assert row["text"] == "n/a (no neural speed)"


def test_warp_embree_and_bvhtree_answer_the_same_secondary_rays_alike(extension):
    """The same AO and shadow rays (Warp's primary hits and normals) through Warp's refit
    BVH, Embree refit and rebuilt, and Blender's BVHTree: the same AO and shadow but for the
    rare ray through an edge."""
    poses = core("blender.poses")
    rays = core("tracing.rays")
    inference = core("inference.secondary")
    made = core("studies.baselines")
    obj = core("studies.side_by_side_scenes").load_side_by_side_scene("lattice")
    captured = core("blender.capture_scene").capture(
        obj, 8, poses.evaluation_spec(poses.PoseSpec(count=1)), deform_corners=False)
    mesh = captured.mesh
    settings = inference.SecondarySettings(samples=8)
    baselines, embree = made.make_baselines(mesh, threads=2)
    try:
        with poses.posed(captured.poses[0]):
            for baseline in baselines:
                baseline.rebuild(obj)
        by_name = {baseline.name: baseline for baseline in baselines}
        origins, directions = rays.orbit_rays(mesh.vertices.min(0), mesh.vertices.max(0),
                                              rays.orbit_viewpoints(1)[0], 48, 48)
        warp = by_name["warp"]
        primary = inference.mesh_primary(warp.vertices, mesh.triangles,
                                         *warp.cast(origins, directions))
        answers = {name: inference.secondary_passes(
            primary, origins, directions, inference.exact_occluded(baseline), mesh.size,
            settings) for name, baseline in by_name.items()}
    finally:
        made.close_baselines(baselines, embree)
    hit = primary.hit
    assert hit.sum() > 100
    rays_cast = hit.sum() * settings.samples
    for name in ("embree_refit", "embree_rebuild", "bvhtree"):
        ao_a, ao_b = answers["warp"].ao[hit], answers[name].ao[hit]
        # some rays are occluded, some are not: the check sees both answers
        assert 0.05 < ao_a.mean() < 0.995
        differing_rays = np.abs(ao_a - ao_b).sum() * settings.samples
        assert differing_rays <= EDGE_SHARE * rays_cast, name
        np.testing.assert_allclose(ao_b, ao_a, atol=2 / settings.samples)
        assert (answers[name].lit != answers["warp"].lit).sum() <= EDGE_SHARE * hit.sum()


def test_the_command_writes_the_secondary_table(extension, tmp_path, capsys):
    """Without a model the neural rows are n/a; every classical path's rates are positive."""
    cli = core("cli")
    secondary = core("studies.side_by_side_secondary")
    code = cli.main(["side-by-side", "--scene", "lattice", "--resolution", "8", "--poses",
                     "1", "--repeats", "1", "--width", "12", "--height", "12", "--threads",
                     "1", "--secondary", "--ao-samples", "3", "--json",
                     str(tmp_path / "sbs.json"), "--markdown", str(tmp_path / "sbs.md")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "secondary rays, 1 AO sample(s): neural n/a; warp " in printed
    data = json.loads((tmp_path / "sbs.json").read_text())
    assert "--secondary --ao-samples 3 --ao-distance 0.1" in data["command"]
    (result,) = data["results"]
    table = result["secondary"]
    assert table["settings"]["samples"] == [1, 3] and table["settings"]["ao_samples"] == 3
    record = result["runs"][0]["poses"][0]
    for name in secondary.SECONDARY_BASELINES:
        for samples in (1, 3):
            figures = table["paths"][name][str(samples)]
            assert math.isfinite(figures["rays_per_s"]) and figures["rays_per_s"] > 0
            assert figures["ao_rays"] == record[f"{name}_hits"] * samples
    assert all(figures["rays_per_s"] is None
               for figures in table["paths"]["neural"].values())
    markdown = (tmp_path / "sbs.md").read_text()
    assert "| Warp refit, 3 AO sample(s): secondary rays/s (rays per pose, ms) |" in markdown
    assert "| where the cheaper side changes: neural / Warp refit | n/a (no neural speed) |" \
        in markdown
