"""The paper's experiments as commands that write their own section of the results file."""

import json
import re
import types

import numpy as np
import pytest
from batch_runner import run_batch


def test_a_section_is_replaced_in_place_and_others_are_kept(tmp_path, core):
    write_section = core("studies.report").write_section
    results = tmp_path / "results.md"
    for key, body in (("experiment static", "first"), ("experiment per-pose", "one"),
                      ("experiment static", "second")):
        write_section(results, key, key.title(), [body], "# Results\n")
    text = results.read_text()
    assert text.startswith("# Results\n\n<!-- experiment static -->\n## Experiment Static")
    assert text.count("<!-- experiment static -->") == 1 and "first" not in text
    assert text.index("second") < text.index("<!-- experiment per-pose -->") < text.index("one")


@pytest.mark.slow
def test_per_pose_experiment_quick(tmp_path):
    results = tmp_path / "docs" / "results.md"
    code, printed, err = run_batch("experiment", "per-pose", "--quick", "--results", results,
                                   timeout=300)
    assert code == 0, err
    text = results.read_text()
    assert "## per-pose: One lsnif per unseen pose" in text
    assert "Command: `python vdnif_addon/batch.py -- experiment per-pose --quick`" in text
    record = json.loads((tmp_path / "docs" / "results" / "per-pose.json").read_text())
    runs = record["runs"]
    assert record["settings"]["eval_poses"] == 2 and set(runs) == {"arm/proposed",
                                                                   "arm/lsnif per pose"}
    for run in runs.values():
        assert {"vs_true", "vs_embedded", "model_bytes"} <= set(run)
    # two per-pose models cost more bytes and training than the one proposed model
    assert runs["arm/lsnif per pose"]["model_bytes"] > runs["arm/proposed"]["model_bytes"]
    assert runs["arm/proposed"]["unseen_poses"] is True
    assert "arm/lsnif per pose: vs true" in printed
    # the run records what produced it, and the machine its training times ran on
    assert {"commit", "network_hash", "network", "recipe", "machine"} <= set(
        record["provenance"])
    assert len(record["provenance"]["machine"]["load_average"]) == 3
    assert "compare them within this table, not with a model trained alone" in text


def metrics(**values):
    """A compare_both result with the same figures against both references."""
    keys = ("distance_mae", "distance_mae_voxels", "normal_error_deg", "hit_iou",
            "false_negative_rate", "false_positive_rate", "compared_rays")
    one = dict(dict.fromkeys(keys, 0.0), **values)
    return {"vs_true": dict(one), "vs_embedded": dict(one)}


def test_medians_over_seeds_are_per_metric_and_none_if_a_seed_has_none(core):
    median_metrics = core("studies.experiment_runs").median_metrics

    seeds = [metrics(distance_mae=0.3, hit_iou=0.9), metrics(distance_mae=0.1, hit_iou=0.7),
             metrics(distance_mae=0.2, hit_iou=0.95)]
    seeds[1]["vs_embedded"]["normal_error_deg"] = None
    median = median_metrics(seeds)
    assert median["vs_true"]["distance_mae"] == 0.2 and median["vs_true"]["hit_iou"] == 0.9
    assert median["vs_true"]["normal_error_deg"] == 0.0
    assert median["vs_embedded"]["normal_error_deg"] is None
    assert median_metrics(seeds[:2])["vs_true"]["distance_mae"] == pytest.approx(0.2)


def test_targets_line_says_what_is_met_and_where_proposed_does_not_beat_deformed(core):
    report = core("studies.report")
    beat_checks, target_checks, targets_line = (report.beat_checks, report.target_checks,
                                                report.targets_line)

    proposed = metrics(distance_mae=0.02, normal_error_deg=12.5, hit_iou=0.99,
                       false_negative_rate=0.004, false_positive_rate=0.006,
                       material_accuracy=0.995)
    proposed["vs_embedded"]["distance_mae"] = 0.05
    deformed = metrics(distance_mae=0.03, normal_error_deg=12.0, hit_iou=0.98,
                       false_negative_rate=0.01, false_positive_rate=0.006,
                       material_accuracy=0.99)
    checks = dict(target_checks("bunny", proposed))
    assert checks == {
        "false negatives 0.4 % / 0.4 % <= 0.5 %": True,
        "false positives 0.6 % / 0.6 % <= 0.5 %": False,
        "distance MAE 0.02 / 0.05 <= 0.039": False,           # met against one reference only
        "normal error 12.5 deg / 12.5 deg <= 11.8 deg": False,
        "material accuracy 0.995 / 0.995 >= 0.99": True}
    assert [text for text, _ in target_checks("spot", proposed, rates=False)] == [
        "distance MAE 0.02 / 0.05 <= 0.039", "normal error 12.5 deg / 12.5 deg <= 11.8 deg",
        "albedo PSNR n/a / n/a >= 30 dB"]
    beaten = dict(beat_checks(proposed, deformed))
    assert len(beaten) == 12                      # 6 metrics with values x 2 references
    assert beaten["distance MAE vs true (0.02 vs 0.03)"]
    assert not beaten["distance MAE vs embedded (0.05 vs 0.03)"]
    assert not beaten["false positives vs true (0.6 % vs 0.6 %)"]      # a tie is no win
    assert beaten["material accuracy vs true (0.995 vs 0.99)"]
    line = targets_line("bunny", proposed, deformed)
    assert line.startswith("- **bunny** (values against the true / embedded reference): "
                           "targets met: false negatives 0.4 % / 0.4 % <= 0.5 %; material")
    assert ("Proposed's median beats deformed's on 7 of 12 metric/reference pairs; **not** "
            "on ") in line
    assert "settle" not in line                   # no seeds given, no verdict
    assert "every metric" in targets_line("arm", deformed, metrics(
        distance_mae=0.04, normal_error_deg=13, hit_iou=0.9, false_negative_rate=0.02,
        false_positive_rate=0.02, material_accuracy=0.5))


def test_a_difference_is_settled_only_where_the_seeds_ranges_do_not_overlap(core):
    report = core("studies.report")
    settled, SETTLED, NOT_SETTLED = report.settled, report.SETTLED, report.NOT_SETTLED
    assert settled([1.0, 1.2, 1.1], [1.3, 1.5, 1.4]) == SETTLED
    assert settled([1.3, 1.5, 1.4], [1.0, 1.2, 1.1]) == SETTLED
    assert settled([1.0, 1.3, 1.1], [1.3, 1.5, 1.4]) == NOT_SETTLED      # touching ranges
    assert settled([1.0, 2.0], [1.4, 1.5]) == NOT_SETTLED                 # one inside
    assert settled([1.0], [2.0]) == NOT_SETTLED                           # one seed
    assert settled([1.0, None, 1.1], [2.0, 2.1]) == SETTLED               # missing skipped

    proposed = [metrics(distance_mae=d, normal_error_deg=3.0, hit_iou=0.9,
                        false_negative_rate=0.004, false_positive_rate=0.004)
                for d in (0.010, 0.011, 0.012)]
    deformed = [metrics(distance_mae=d, normal_error_deg=n, hit_iou=0.9,
                        false_negative_rate=0.004, false_positive_rate=0.004)
                for d, n in ((0.020, 2.0), (0.021, 4.0), (0.022, 5.0))]
    median = report.beat_checks(proposed[1], deformed[1], (proposed, deformed))
    texts = dict(median)
    assert texts["distance MAE vs true (0.011 vs 0.021, settled)"]
    assert texts["normal error vs true (3 deg vs 4 deg, not settled)"]
    line = report.targets_line("arm", proposed[1], deformed[1], seeds=(proposed, deformed))
    assert "The seeds settle 2 of the 4 it wins" in line


def test_each_ablation_takes_one_part_of_proposed_back_to_the_baseline(core):
    variant_config = core("model.variants").variant_config
    ABLATIONS, VARIANTS = core("settings").ABLATIONS, core("settings").VARIANTS

    proposed, deformed = variant_config("proposed"), variant_config("deformed")
    parts = {"pe_bands": "network", "distance_mode": "network", "weighting": "train"}
    for name, removed in ABLATIONS.items():
        ablated = variant_config(name)
        assert ablated.deformed_data
        for key, part in parts.items():
            expected = deformed if key == removed else proposed
            assert getattr(getattr(ablated, part), key) == getattr(getattr(expected, part), key)
    assert set(ABLATIONS.values()) == set(parts) and set(ABLATIONS) <= set(VARIANTS)


def test_original_is_the_rest_mesh_cast_with_the_rays_of_the_deformed_view(empty_scene, core):
    """The "original" column: Blender's BVHTree on the rest mesh, cast with the evaluation
    view's rays (the orbit camera framing the deformed pose), gives the same hits."""
    experiment_runs = core("studies.experiment_runs")
    size = dict(experiment_runs.SIZES["quick"], eval_poses=2, width=20, height=20)
    run = experiment_runs.Experiment(size, "/nonexistent", None, "cpu", None, ("lattice",))
    obj, captured = run.scene("lattice")
    evaluated = run.evaluation(obj)
    runs = types.SimpleNamespace(obj=obj, evaluated=evaluated, captured=captured)
    original = experiment_runs.original_views(run, runs)
    mesh = captured.mesh
    tree = core("blender.bvh").BVHCaster(mesh.vertices, mesh.triangles)
    neural, rays = core("posed.render"), core("tracing.rays")
    viewpoints = rays.orbit_viewpoints(2)
    with core("posed.geometry").PosedObject(obj, evaluated) as posed_object:
        for pose, viewpoint, passes in zip(evaluated.poses, viewpoints, original):
            geometry = posed_object.geometry(pose)
            origins, directions = neural.orbit_view(geometry, viewpoint, 20, 20)
            index, t = tree.cast(origins, directions, np.full(len(origins), np.inf))
            assert 50 < passes.hit.sum() < 400
            np.testing.assert_array_equal(passes.hit, index >= 0)
            np.testing.assert_allclose(passes.distance[passes.hit], t[index >= 0], rtol=1e-5)
            deformed = core("tracing.references").true_reference(
                mesh, geometry.mesh_caster(mesh.triangles), origins, directions)
            both = deformed.hit & passes.hit            # the pose moved the object
            assert (deformed.hit != passes.hit).any()
            assert np.abs(deformed.distance[both] - passes.distance[both]).max() > 0.01


@pytest.mark.slow
def test_deformation_experiment_quick(tmp_path):
    """Figure 3 on the textured spot and the three-material bunny: medians over the quick
    size's two seeds on one common pixel set, the original column, targets, figures."""
    results = tmp_path / "docs" / "results.md"
    code, printed, err = run_batch("experiment", "deformation", "--quick", "--scenes",
                                   "spot,bunny", "--results", results, timeout=600)
    assert code == 0, err
    text = results.read_text()
    assert "Command: `python vdnif_addon/batch.py -- experiment deformation --quick --scenes " \
           "spot,bunny`" in text
    # narrowed to two of its four scenes: its own section and JSON beside the whole run's
    assert "<!-- experiment deformation, spot, bunny -->" in text
    record = json.loads((tmp_path / "docs" / "results" / "deformation-spot-bunny.json")
                        .read_text())
    runs = record["runs"]
    assert record["settings"]["seeds"] == [0, 1] and record["scenes"] == ["spot", "bunny"]
    assert set(runs) == {f"{scene}/{label}" for scene in ("spot", "bunny")
                         for label in ("deformed", "proposed", "original (rest pose)")}
    for scene in ("spot", "bunny"):
        for label in ("deformed", "proposed"):
            run = runs[f"{scene}/{label}"]
            assert [seed["seed"] for seed in run["seeds"]] == [0, 1]
            assert all(seed["unseen_poses"] for seed in run["seeds"])
            pixels = {seed["common"]["vs_true"]["compared_rays"] for seed in run["seeds"]}
            assert len(pixels) == 1                              # one common pixel set
            iou = sorted(seed["common"]["vs_true"]["hit_iou"] for seed in run["seeds"])
            assert run["common"]["vs_true"]["hit_iou"] == pytest.approx(sum(iou) / 2)
            assert run["seeds"][0]["validation_history"][-1]["step"] == 20
        original = runs[f"{scene}/original (rest pose)"]["vs_true"]
        assert 0 < original["hit_iou"] < 1
    assert runs["spot/original (rest pose)"]["vs_true"]["albedo_psnr"] is not None
    assert runs["bunny/original (rest pose)"]["vs_true"]["material_accuracy"] > 0.5
    assert "| spot: original (rest pose) | true |" in text
    assert "- **bunny** (values against the true / embedded reference): targets met:" in text
    assert "material accuracy" in text and "albedo PSNR" in text
    for scene in ("spot", "bunny"):
        figure = tmp_path / "docs" / "results" / f"deformation-{scene}.png"
        assert figure.stat().st_size > 1000 and f"(results/deformation-{scene}.png)" in text
    assert "columns: deformed, proposed, reference, original, error of deformed, error of " \
           "proposed" in text
    assert "spot/original (rest pose): vs true" in printed


@pytest.mark.slow
def test_ablation_experiment_quick(tmp_path, core):
    """The ablation end to end on one scene and seed: each run trains the configuration it
    names (one part of proposed taken back to the baseline's) on the same data and steps."""
    results = tmp_path / "docs" / "results.md"
    code, printed, err = run_batch("experiment", "ablation", "--quick", "--scenes", "arm",
                                   "--seeds", "1", "--results", results, timeout=600)
    assert code == 0, err
    record = json.loads((tmp_path / "docs" / "results" / "ablation-arm-1-seed.json")
                        .read_text())
    assert record["scenes"] == ["arm"] and record["settings"]["seeds"] == [0]
    configs = {}
    for label in ("deformed", "proposed", "no positional encoding", "no log distance",
                  "no uncertainty weighting", "proposed, sin(pi 2^k x)",
                  "proposed, log-MSE of d/h"):
        (seed,) = record["runs"][f"arm/{label}"]["seeds"]
        assert seed["unseen_poses"] and seed["validation_history"][-1]["step"] == 20
        assert seed["dataset"] == record["runs"]["arm/proposed"]["seeds"][0]["dataset"]
        config = seed["config"]
        configs[label] = (config["network"]["pe_bands"], config["network"]["pe_form"],
                          config["network"]["distance_mode"], config["train"]["weighting"])
    assert configs == {
        "deformed": (0, "paper", "fraction", "fixed"),
        "proposed": (3, "paper", "log1p-fraction", "uncertainty"),
        "no positional encoding": (0, "paper", "log1p-fraction", "uncertainty"),
        "no log distance": (3, "paper", "fraction", "uncertainty"),
        "no uncertainty weighting": (3, "paper", "log1p-fraction", "fixed"),
        "proposed, sin(pi 2^k x)": (3, "pi", "log1p-fraction", "uncertainty"),
        "proposed, log-MSE of d/h": (3, "paper", "log-distance", "uncertainty")}
    text = results.read_text()
    assert "Command: `python vdnif_addon/batch.py -- experiment ablation --quick --scenes arm " \
           "--seeds 1`" in text
    assert "| arm: no log distance | true |" in text and "- arm: no positional encoding:" in text
    paper_loss = core("studies.experiment_runs").PAPER_LOSS
    assert f"`{paper_loss}` is proposed with the paper's distance" in text
    assert not re.search(r"\{[A-Z_]+\}", text), "a name left unformatted"
    # one seed settles nothing
    assert "(not settled)" in text and "(settled)" not in text
    assert "<!-- experiment ablation, arm, 1 seed -->" in text
    assert re.search(r"Ran on \d{4}-\d\d-\d\d from \d\d:\d\d to \d\d:\d\d UTC \(wall "
                     r"\d+ min, torch on \d+ threads?, \d+ CPU cores\)\.", text)


def test_a_narrowed_run_names_its_scenes_and_seeds(core):
    """A run of some scenes or fewer seeds writes its own section, JSON and figures, so a
    one-seed run never replaces the section of the run over every seed."""
    experiments = core("studies.experiments")
    name = experiments.run_name
    assert name("deformation", ("arm", "lattice", "spot", "bunny"), (0, 1, 2), (0, 1, 2)) == (
        "experiment deformation", "deformation", "")
    assert name("deformation", ("spot",), (0, 1, 2), (0, 1, 2)) == (
        "experiment deformation, spot", "deformation-spot", "")
    assert name("deformation", ("spot",), (0,), (0, 1, 2)) == (
        "experiment deformation, spot, 1 seed", "deformation-spot-1-seed", "-1-seed")
    assert name("static", ("bunny", "spot"), (0, 1), (0, 1, 2)) == (
        "experiment static, 2 seeds", "static-2-seeds", "-2-seeds")
    # a run that crosses midnight names both days
    started = experiments.datetime.datetime(2000, 1, 1, 23, 50,
                                            tzinfo=experiments.datetime.timezone.utc)
    ended = started + experiments.datetime.timedelta(minutes=50)
    assert experiments.ran_line(started, 50 * 60, 1).startswith(
        f"Ran on {started:%Y-%m-%d}/{ended:%d} from 23:50 to 00:40 UTC (wall 50 min, torch on "
        "1 thread, ")
