"""The side-by-side comparison on a tiny scene: every path timed, speeds only from a model
that predicts hits (n/a with the reason otherwise), the tables, plots and the performance
section written from it, and the command's options."""

import dataclasses
import importlib
import json
import math
import types

import numpy as np
import pytest
import torch
from conftest import EXTENSION_MODULE

RAYS = 16


def core(name):
    return importlib.import_module(f"{EXTENSION_MODULE}.vdnif_addon.{name}")


class OracleNetwork:
    """Answers every segment with its exact rest-space ground truth: a model that predicts
    hits as well as the voxel embedding allows (its hit IoU against the true reference is
    that of the embedded reference)."""

    def __init__(self, mesh, grid):
        groundtruth = core("tracing.groundtruth")
        self.mesh, self.grid, self.targets = mesh, grid, groundtruth.segment_targets
        self.caster = groundtruth.rest_surface(mesh)

    def parameters(self):
        """No weights: it answers on the device its inputs are on."""
        return iter(())

    def predict(self, p0, p1, rest_len, voxel_size):
        to_rest = lambda p: p.double().numpy() * self.grid.extent + self.grid.origin  # noqa: E731
        count = len(p0)
        segments = core("geometry.walk_rules").Segments(
            ray=np.arange(count), cell=np.zeros(count, int), t0=np.zeros(count),
            t1=np.ones(count), p0=to_rest(p0), p1=to_rest(p1))
        hits = self.targets(self.mesh, self.caster, segments)
        length = rest_len.double().numpy()
        return {"hit": torch.as_tensor(hits.hit), "candidate": torch.as_tensor(hits.hit),
                "fraction": torch.as_tensor(hits.distance / np.maximum(length, 1e-30)),
                "normal": torch.as_tensor(hits.normal),
                "material": torch.as_tensor(hits.material.astype(np.int64))}


class NeverHits(OracleNetwork):
    """The oracle's work, but it never says hit: a model that predicts no hits."""

    def predict(self, p0, p1, rest_len, voxel_size):
        prediction = super().predict(p0, p1, rest_len, voxel_size)
        return dict(prediction, hit=torch.zeros_like(prediction["hit"]),
                    candidate=torch.zeros_like(prediction["hit"]))


def stand_in_model(network, capture, path):
    """What compare_paths reads of a neural.SceneModel, around ``network``."""
    path.write_bytes(b"\0" * 1000)
    return types.SimpleNamespace(network=network, albedo_table=capture.mesh.albedo_table(),
                                 device=torch.device("cpu"), path=str(path),
                                 variant=type(network).__name__)


@pytest.fixture(scope="module")
def tiny(extension, tmp_path_factory):
    """compare_paths on the lattice demo's Suzanne (3,936 triangles) at R 8, 2 unseen poses,
    16x16 rays, one repeat: without a model, with the oracle, with one that never hits."""
    side = core("studies.side_by_side")
    poses = core("blender.poses")
    obj = side.load_side_by_side_scene("lattice")
    captured = core("blender.capture_scene").capture(
        obj, 8, poses.evaluation_spec(poses.PoseSpec(count=2)), deform_corners=False)
    folder = tmp_path_factory.mktemp("models")
    results = {"none": side.compare_paths(obj, captured, None, RAYS, RAYS, repeats=1)}
    networks = {"oracle": OracleNetwork(captured.mesh, captured.grid),
                "never": NeverHits(captured.mesh, captured.grid),
                "untrained": untrained_network(captured.mesh)}
    for name, network in networks.items():
        model = stand_in_model(network, captured, folder / f"{name}.vdnif")
        results[name] = side.compare_paths(obj, captured, model, RAYS, RAYS, repeats=1)
    return side, results


def untrained_network(mesh):
    """The product's network in the paper's configuration with the scene's heads, as
    initialized (seed 0), never trained."""
    network, settings = core("model.network"), core("settings")
    config = dataclasses.replace(settings.NetworkConfig(),
                                 heads=settings.Heads.from_header(mesh.heads()))
    with torch.random.fork_rng():
        torch.manual_seed(0)
        return network.IntersectionNetwork(config).eval()


def timings(result):
    return {key: value for run in result["runs"] for record in run["poses"] + run["rest"]
            for key, value in record.items() if key.endswith("_s")}


def test_every_baseline_is_timed_and_hits_what_the_true_reference_hits(tiny):
    side, results = tiny
    baselines = core("studies.baselines").BASELINES
    for result in results.values():
        assert result["repeats"] == 1 and result["poses"] == 2 and result["rays"] == RAYS ** 2
        seconds = timings(result)
        for name in baselines:
            for step in ("evaluate_s", "rebuild_s", "cast_s"):
                assert f"{name}_{step}" in seconds
            assert result["rays_per_s"][name] > 0
            assert result["ratios"][f"prepare_neural_over_{name}"] > 0
            agreement = result["agreement"][name]
            assert agreement["rays"] == 2 * RAYS ** 2 and agreement["differing_hits"] == 0
            assert agreement["both_hit"] > 20 and agreement["max_distance_difference"] < 1e-5
        assert {"warp_read_s", "warp_refit_s", "embree_copy_s", "embree_commit_s",
                "bvhtree_build_s", "neural_prepare_s"} <= set(seconds)
        assert all(math.isfinite(t) and t > 0 for t in seconds.values())
        assert result["segments_match"]                     # DDA walks the same cells
        assert result["median"]["deformed_walk_segments"] == result["median"]["walk_segments"]
        assert result["ratios"]["walk_deformed_over_static"] > 0
        sizes = result["bytes"]
        assert sizes["mesh"] == 12 * (2012 + 3936)
        assert set(sizes["bvh"]) == set(baselines) and all(b > sizes["mesh"]
                                                           for b in sizes["bvh"].values())


def test_without_a_model_the_neural_side_is_not_run(tiny):
    side, results = tiny
    result = results["none"]
    assert result["speed_withheld"] == side.NO_MODEL and not result["network"]["trained"]
    assert result["rays_per_s"]["neural"] is None
    assert not any(key.startswith("neural_render") for key in timings(result))
    assert "all_segments_network_s" not in timings(result)
    assert result["ratios"]["walk_and_network_deformed_over_static"] is None
    assert all(result["ratios"][f"{kind}_neural_over_bvhtree"] is None
               for kind in ("render", "pose"))
    assert "paper's configuration" in result["bytes"]["model_source"]


def test_a_model_that_predicts_hits_has_speeds(tiny):
    _, results = tiny
    result = results["oracle"]
    network = result["network"]
    assert network["trained"] and network["hit_iou"] >= 0.9
    assert result["speed_withheld"] is None
    assert result["rays_per_s"]["neural"] > 0
    assert all(value is not None and value > 0 for value in result["ratios"].values())
    median = result["median"]
    assert median["neural_hits"] > 20 and median["neural_segments"] > 0
    # the renderer stops a ray at its hit: it evaluates fewer segments than the walk has
    assert median["neural_segments"] < median["walk_segments"]
    assert result["bytes"]["model"] == 1000 and result["bytes"]["model_source"] == "model file"


def test_a_model_that_predicts_no_hits_gets_no_speed_with_the_reason(tiny):
    _, results = tiny
    result = results["never"]
    assert result["network"]["hit_iou"] == 0.0
    assert result["speed_withheld"] == core("inference.metrics").speed_withheld(0.0)
    assert "below 0.9" in result["speed_withheld"]
    assert result["rays_per_s"]["neural"] is None
    assert not any(key.startswith(("neural_render", "neural_walk", "neural_network"))
                   for key in timings(result))
    assert "neural_render_s" not in result["median"]
    for name in core("studies.baselines").BASELINES:
        assert result["ratios"][f"render_neural_over_{name}"] is None
        assert result["ratios"][f"pose_neural_over_{name}"] is None
        assert result["ratios"][f"prepare_neural_over_{name}"] > 0
    # the network over every walked segment does not depend on what it predicts
    assert result["ratios"]["walk_and_network_deformed_over_static"] > 0


def test_an_untrained_network_gets_no_speed_with_the_reason(tiny):
    """The real network (Warp encoder, MLP, heads) before training: whatever it happens to
    predict, its hit IoU against the true reference is far below 0.9, so it has no speed."""
    _, results = tiny
    result = results["untrained"]
    network = result["network"]
    assert network["trained"] and network["hit_iou"] < 0.5
    assert result["speed_withheld"] == core("inference.metrics").speed_withheld(network["hit_iou"])
    assert "below 0.9" in result["speed_withheld"]
    assert result["rays_per_s"]["neural"] is None
    assert "neural_render_s" not in result["median"]
    assert all(result["ratios"][f"{kind}_neural_over_{name}"] is None
               for kind in ("render", "pose") for name in core("studies.baselines").BASELINES)
    # the network did run: over every walked segment of the rest views, untimed as a speed
    assert result["ratios"]["walk_and_network_deformed_over_static"] > 0


def test_markdown_says_every_figure_and_why_one_is_missing(tiny):
    _, results = tiny
    report = core("studies.side_by_side_report")
    rows = [results["oracle"], results["never"], results["none"]]
    text = "\n".join(report.side_by_side_markdown(rows, command="python batch.py -- x"))
    assert "Command: `python batch.py -- x`" in text
    for label, _ in report.STEP_ROWS:
        assert label in text
    for label, *_ in report.TARGETS:
        assert label in text
    tables = [line for line in text.splitlines() if line.startswith("| | ")]
    assert len(tables) == 9 and all(line.count("Suzanne (3,936 triangles)") == 3
                                    for line in tables)
    assert results["never"]["speed_withheld"] in text and results["none"]["speed_withheld"] in text
    speed_row = next(line for line in text.splitlines()
                     if line.startswith("| neural render (walk"))
    assert speed_row.count("n/a") == 2 and f"{results['oracle']['rays_per_s']['neural']:,.0f}" \
        in speed_row
    walk = results["oracle"]["ratios"]["walk_deformed_over_static"]
    row = next(line for line in text.splitlines()
               if line.startswith(f"| walk: deformed / static DDA <= {report.TARGET_WALK} |"))
    assert row.split("|")[2].strip() == (
        f"{walk:.3g}" + (" (met)" if walk <= report.TARGET_WALK else " (**missed**)"))
    assert "| DDA and deformed walk give the same cells | yes |" in "\n".join(
        report.side_by_side_markdown([results["oracle"]]))
    # where the walks differ the settings say how many segments each walked
    median = dict(results["oracle"]["median"], deformed_walk_segments=1234, walk_segments=1200)
    differing = dict(results["oracle"], segments_match=False, median=median)
    assert ("| DDA and deformed walk give the same cells | no, on some rest view; segments per "
            "rest view (median): 1,234 deformed, 1,200 static |") in "\n".join(
        report.side_by_side_markdown([differing]))


def test_plots_and_the_performance_section(tiny, tmp_path):
    _, results = tiny
    report = core("studies.side_by_side_report")
    performance = tmp_path / "performance.md"
    performance.write_text("# Performance\n\n<!-- bench -->\n## Sweep\nkept\n<!-- end bench -->\n")
    machine = {"cpu": "test CPU", "cores": 2, "load_before": 0.5, "load_after": 0.7,
               "omp_num_threads": "1", "torch": "2", "torch_threads": 1, "warp": "1",
               "warp_device": "cpu", "embreex": "4", "blender": "4.5"}
    rows = [results["oracle"], results["never"]]
    for _ in range(2):                      # rewriting keeps one section and the other one
        paths = report.write_performance(performance, rows, "python batch.py -- y", machine)
    text = performance.read_text()
    assert text.count("<!-- side-by-side -->") == 1 and "kept" in text
    assert "test CPU, 2 cores" in text and "OMP_NUM_THREADS=1" in text
    for name, path in paths.items():
        assert path.parent == tmp_path / "side-by-side"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000
        assert f"](side-by-side/{path.name})" in text


def test_the_command_writes_json_plots_and_section(extension, tmp_path, capsys):
    cli = core("cli")
    performance = tmp_path / "performance.md"
    code = cli.main(["side-by-side", "--scene", "lattice", "--resolution", "8",
                          "--poses", "1", "--repeats", "1", "--width", "8", "--height", "8",
                          "--json", str(tmp_path / "sbs.json"),
                          "--plots", str(tmp_path / "plots"),
                          "--markdown", str(tmp_path / "sbs.md"),
                          "--performance", str(performance)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "side by side 'Suzanne' (3,936 triangles)" in printed and "n/a" in printed
    data = json.loads((tmp_path / "sbs.json").read_text())
    assert data["machine"]["cores"] >= 1 and data["machine"]["warp_device"] == "cpu"
    assert data["command"].endswith("--performance " + str(performance))
    assert data["results"][0]["speed_withheld"] == core("studies.side_by_side").NO_MODEL
    assert (tmp_path / "plots" / "side-by-side-speed.png").exists()
    assert "Machine: " in (tmp_path / "sbs.md").read_text()
    assert "## Side by side with the classical baselines" in performance.read_text()


def test_bad_settings_are_one_line(extension, tmp_path, capsys):
    side = core("studies.side_by_side")
    errors = core("errors")
    with pytest.raises(errors.VDNIFError, match="unknown scene 'teapot'"):
        side.load_side_by_side_scene("teapot")
    assert side.scene_name("million") == "suzanne-5"
    cli = core("cli")
    for argv, message in (
            (["--scene", "bunny", "lattice", "--model", "m.vdnif"], "name the scene of each"),
            (["--scene", "bunny", "--model", "lattice=m.vdnif"], "'lattice' is not among"),
            (["--scene", "lattice", "--repeats", "0", "--resolution", "8", "--poses", "1"],
             "repeats 0 must be at least 1")):
        assert cli.main(["side-by-side", *argv]) == 1
        assert message in capsys.readouterr().err
