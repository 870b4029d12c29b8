"""The side-by-side comparison on a tiny scene: every path timed, speeds only from a model
that predicts hits (n/a with the reason otherwise), the tables, plots and the performance
section written from it, and the command's options.

With secondary rays, every path casts as many AO rays as its primary hits times the samples
and at most one shadow ray per hit, at 1 and N samples in one run, each rate positive and
finite; each path's rays are answered by its own occluder (the network's by the network);
Warp's, Embree's and Blender's BVHTree's answers to the same secondary rays agree (three
independent ray casters); where the cheaper side changes is exact for totals linear in the
samples; and the command writes the table."""

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
SAMPLES = 4           # AO samples per pixel of the secondary-ray runs
EDGE_SHARE = 0.01     # secondary rays through an edge or a vertex that casters may split


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
        self.precision = "float32"          # exact answers: no arithmetic to lower

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


def lattice_capture(poses):
    """The lattice demo's Suzanne and its capture at R 8 on ``poses`` unseen poses."""
    obj = core("studies.side_by_side_scenes").load_side_by_side_scene("lattice")
    spec = core("blender.poses").evaluation_spec(core("blender.poses").PoseSpec(count=poses))
    return obj, core("blender.capture_scene").capture(obj, 8, spec, deform_corners=False)


def stand_in_model(network, capture, path):
    """What compare_paths reads of a neural.SceneModel, around ``network``."""
    path.write_bytes(b"\0" * 1000)
    network_offset = core("inference.secondary").network_offset
    return types.SimpleNamespace(network=network, albedo_table=capture.mesh.albedo_table(),
                                 device=torch.device("cpu"), path=str(path),
                                 variant=type(network).__name__,
                                 secondary_offset=lambda size: network_offset(
                                     size, capture.grid.voxel_size))


@pytest.fixture(scope="module")
def tiny(extension, tmp_path_factory):
    """compare_paths on the lattice demo's Suzanne (3,936 triangles) at R 8, 2 unseen poses,
    16x16 rays, one repeat: without a model, with the oracle, with one that never hits."""
    side = core("studies.side_by_side")
    obj, captured = lattice_capture(2)
    folder = tmp_path_factory.mktemp("models")
    results = {"none": side.compare_paths(obj, captured, None, RAYS, RAYS, repeats=1),
               "none, 2 threads": side.compare_paths(obj, captured, None, RAYS, RAYS,
                                                     repeats=1, threads=2)}
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
            for step in ("evaluate_s", "build_s", "pose_s", "cast_s"):
                assert f"{name}_{step}" in seconds
            assert result["rays_per_s"][name] > 0
            assert result["ratios"][f"prepare_neural_over_{name}"] > 0
            agreement = result["agreement"][name]
            assert agreement["rays"] == 2 * RAYS ** 2 and agreement["differing_hits"] == 0
            assert agreement["both_hit"] > 20 and agreement["max_distance_difference"] < 1e-5
        assert {"warp_read_s", "embree_refit_read_s", "embree_rebuild_read_s",
                "neural_prepare_s"} <= set(seconds)
        for record in (r for run in result["runs"] for r in run["poses"]):
            for name in baselines:           # a pose's preparation is the sum of its steps
                steps = [record.get(f"{name}_{step}", 0.0)
                         for step in ("evaluate_s", "read_s", "build_s")]
                assert record[f"{name}_pose_s"] == pytest.approx(sum(steps))
        assert all(math.isfinite(t) and t > 0 for t in seconds.values())
        assert result["segments_match"]                     # DDA walks the same cells
        assert result["median"]["deformed_walk_segments"] == result["median"]["walk_segments"]
        assert result["ratios"]["walk_deformed_over_static"] > 0
        sizes = result["bytes"]
        assert sizes["mesh"] == 12 * (2012 + 3936)
        assert set(sizes["bvh"]) == set(baselines) and all(b > sizes["mesh"]
                                                           for b in sizes["bvh"].values())


def test_every_row_says_how_many_threads_it_used(tiny):
    _, results = tiny
    report = core("studies.side_by_side_report")
    blender = core("studies.baselines").BLENDER_THREADS
    lane_rays = core("threads").MIN_LANE_RAYS
    for key, setting in (("none", 1), ("none, 2 threads", 2)):
        result = results[key]
        assert result["threads"] == {
            "setting": setting, "torch": 1, "encoder": setting,
            "walk_lanes": max(1, min(setting, RAYS * RAYS // lane_rays)),
            "bvhtree": {"build": blender, "casts": 1},
            "warp": {"build": 1, "casts": setting},
            "embree_refit": {"build": setting, "casts": setting},
            "embree_rebuild": {"build": setting, "casts": setting}}
        assert result["embree"]["width"] == 16 and result["embree"]["version"] >= 40000
    text = "\n".join(report.side_by_side_markdown([results["none"],
                                                    results["none, 2 threads"]]))
    assert ("| Embree refit: threads | refit on 1 thread(s), casts on 1 thread(s) | refit on "
            "2 thread(s), casts on 2 thread(s) |") in text
    assert ("| BVHTree (Python loop): threads | rebuild on Blender's threads, casts on 1 "
            "thread(s) | rebuild on Blender's threads, casts on 1 thread(s) |") in text
    assert ("| Warp refit: threads | refit on 1 thread(s), casts on 1 thread(s) | refit on 1 "
            "thread(s), casts on 2 thread(s) |") in text
    assert "Suzanne (3,936 triangles), 16x16, 2 thread setting" in text
    side = core("studies.side_by_side")
    cores = core("threads").machine_cores()
    assert side.thread_settings(["1", "all", "1"]) == sorted({1, cores})
    assert [side.torch_setting(n) for n in (1, 2, 16)] == [1, 1, 15]


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
    # at a glance: a row per result, the neural pose over the cheapest classical one
    plots = core("studies.side_by_side_report")
    oracle = results["oracle"]
    baselines = core("studies.baselines").BASELINES
    cheapest = min(baselines, key=lambda b: plots.pose_total(oracle, b))
    glance = [line for line in text.splitlines()
              if line.startswith("| Suzanne (3,936) | 16x16 | 1 |")]
    assert len(glance) == 3
    assert glance[0].split("|")[-3].strip() == (
        f"{oracle['ratios'][f'pose_neural_over_{cheapest}']:.3g} "
        f"({plots.SHORT[cheapest]})")
    assert glance[2].split("|")[-3].strip() == "n/a"               # no model
    tables = [line for line in text.splitlines() if line.startswith("| | ")]
    assert len(tables) == 9 and all(
        line.count("Suzanne (3,936 triangles), 16x16, 1 thread setting") == 3
        for line in tables)
    assert results["never"]["speed_withheld"] in text and results["none"]["speed_withheld"] in text
    speed_row = next(line for line in text.splitlines()
                     if line.startswith("| neural render (walk"))
    assert speed_row.count("n/a") == 2 and f"{results['oracle']['rays_per_s']['neural']:,.0f}" \
        in speed_row
    # the network's share: its segments/s in the render's waves over one batch's
    median = results["oracle"]["median"]
    share = (median["neural_segments"] * median["all_segments_network_s"]) / (
        median["neural_network_s"] * median["walk_segments"])
    row = next(line for line in text.splitlines() if line.startswith("| network inside"))
    assert row.split("|")[2].strip().startswith(f"{share * 100:.0f} %")
    assert row.split("|")[4].strip() == "n/a"                     # no model: not rendered
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
    machine = {"cpu": "test CPU", "vector": "AVX2", "cores": 2, "load_before": 0.5,
               "load_after": 0.7,
               "omp_num_threads": "1", "torch": "2", "torch_threads": 1, "warp": "1",
               "warp_device": "cpu", "embreex": "4", "blender": "4.5"}
    rows = [results["oracle"], results["never"]]
    for _ in range(2):                      # rewriting keeps one section and the other one
        paths = report.write_performance(performance, rows, "python batch.py -- y", machine)
    text = performance.read_text()
    assert text.count("<!-- side-by-side -->") == 1 and "kept" in text
    assert "test CPU (AVX2), 2 cores" in text and "OMP_NUM_THREADS=1" in text
    for name, path in paths.items():
        assert path.parent == tmp_path / "side-by-side"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000
        assert f"](side-by-side/{path.name})" in text


def test_the_machine_names_its_widest_vector_extensions(extension):
    """The report names AVX-512 (with BF16 and AMX) or AVX2 from the CPU's flags."""
    widest = core("kernels.runtime").vector_extensions
    assert widest({"avx2", "avx512f", "avx512_bf16"}) == "AVX-512 with BF16"
    assert (widest({"avx2", "avx512f", "avx512_bf16", "amx_bf16", "amx_tile"})
            == "AVX-512 with BF16 and AMX")
    assert widest({"avx2", "avx512f"}) == "AVX-512"
    assert widest({"avx", "avx2", "fma"}) == "AVX2"
    assert widest({"sse4_2"}) == "no AVX2"


def test_the_command_writes_json_plots_and_section(extension, tmp_path, capsys):
    cli = core("cli")
    performance = tmp_path / "performance.md"
    code = cli.main(["side-by-side", "--scene", "lattice", "--resolution", "8",
                     "--poses", "1", "--repeats", "1", "--width", "8", "--height", "8",
                     "--threads", "1", "2", "--json", str(tmp_path / "sbs.json"),
                     "--plots", str(tmp_path / "plots"),
                     "--markdown", str(tmp_path / "sbs.md"),
                     "--performance", str(performance)])
    assert code == 0
    printed = capsys.readouterr().out
    for setting in (1, 2):
        assert (f"side by side 'Suzanne' (3,936 triangles), 8x8, {setting} thread setting"
                in printed)
    data = json.loads((tmp_path / "sbs.json").read_text())
    assert data["machine"]["cores"] >= 1 and data["machine"]["warp_device"] == "cpu"
    assert data["command"].endswith("--threads 1 2 --device cpu --json "
                                    f"{tmp_path / 'sbs.json'} --markdown {tmp_path / 'sbs.md'} "
                                    f"--plots {tmp_path / 'plots'} --performance "
                                    f"{performance}")
    assert [r["threads"]["setting"] for r in data["results"]] == [1, 2]
    for result in data["results"]:
        assert result["speed_withheld"] == core("studies.side_by_side").NO_MODEL
        for name in core("studies.baselines").BASELINES:
            assert result["agreement"][name]["differing_hits"] == 0
            assert result["rays_per_s"][name] > 0
    assert (tmp_path / "plots" / "side-by-side-speed.png").exists()
    markdown = (tmp_path / "sbs.md").read_text()
    assert "Machine: " in markdown and "| Embree rebuild: threads |" in markdown
    assert "## Side by side with the classical baselines" in performance.read_text()


@pytest.mark.slow
def test_the_crossover_command_trains_missing_models_and_writes_its_files(extension,
                                                                          tmp_path, capsys):
    """Two Suzanne meshes, models trained by the quick size (they predict no hits, so the
    crossover is n/a with the reason), 8x8 views and the 4x4 preview, one thread setting."""
    cli = core("cli")
    out, models = tmp_path / "crossover", tmp_path / "models"
    argv = ["side-by-side", "--scene", "suzanne-2", "suzanne-3", "--poses", "1", "--repeats",
            "1", "--width", "8", "--height", "8", "--preview", "4", "--threads", "1",
            "--train", str(models), "--quick", "--crossover", str(out)]
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    mark = core("output_rule").OUTPUT_MARK            # the folder's mark as VDNIF's
    assert sorted(path.name for path in models.iterdir()
                  if path.name != mark) == ["suzanne-2.vdnif", "suzanne-3.vdnif"]
    data = json.loads((out / "crossover.json").read_text())
    assert data["command"].endswith(
        "side-by-side --scene suzanne-2 suzanne-3 --poses 1 --seed 0 --repeats 1 --width 8 "
        f"--height 8 --threads 1 --device cpu --quick --preview 4 --train {models} "
        f"--crossover {out}")
    groups = {(row["width"], row["height"], row["threads"]) for row in data["rows"]}
    assert groups == {(8, 8, 1), (4, 4, 1)}
    assert len(data["rows"]) == 2 * len(core("studies.baselines").BASELINES)
    assert all(row["triangles"] is None and row["text"].startswith("n/a (no neural speed")
               for row in data["rows"])
    assert [mesh["triangles"] for mesh in data["bytes"]] == [15744, 62976]
    markdown = (out / "crossover.md").read_text()
    assert markdown.startswith(f"Command: `{data['command']}`")
    assert "| Embree refit | **n/a (no neural speed on" in markdown
    assert (out / "crossover.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "crossover 4x4, 1 thread setting, warp: n/a" in captured.out
    # a second run uses the models it trained
    assert cli.main(argv[:-2]) == 0
    assert "uses the model" in capsys.readouterr().err


def test_bad_settings_are_one_line(extension, tmp_path, capsys):
    scenes = core("studies.side_by_side_scenes")
    errors = core("errors")
    with pytest.raises(errors.VDNIFError, match="unknown scene 'teapot'"):
        scenes.load_side_by_side_scene("teapot")
    assert scenes.scene_name("million") == "suzanne-5"
    cli = core("cli")
    for argv, message in (
            (["--scene", "bunny", "lattice", "--model", "m.vdnif"], "name the scene of each"),
            (["--scene", "bunny", "--model", "lattice=m.vdnif"], "'lattice' is not among"),
            (["--scene", "lattice", "--repeats", "0", "--resolution", "8", "--poses", "1"],
             "repeats 0 must be at least 1"),
            (["--scene", "lattice", "--threads", "0"], "thread setting '0' must be a count"),
            (["--scene", "lattice", "--threads", "two"], "thread setting 'two' must be"),
            (["--scene", "bunny", "suzanne-2", "--crossover", str(tmp_path)],
             "--crossover needs at least two suzanne-N scenes")):
        assert cli.main(["side-by-side", *argv]) == 1
        assert message in capsys.readouterr().err


def fake_result(scene, triangles, neural_ms, classical_ms, size=256, setting=2):
    """A compare_paths result with only what the crossover reads: pose totals in ms (neural
    None: withheld), each baseline's split evenly between its preparation and its casts."""
    baselines = core("studies.baselines").BASELINES
    median = {} if neural_ms is None else {"neural_pose_s": neural_ms / 2e3,
                                           "neural_render_s": neural_ms / 2e3}
    for name in baselines:
        median.update({f"{name}_pose_s": classical_ms[name] / 2e3,
                       f"{name}_cast_s": classical_ms[name] / 2e3})
    mesh = 24 * triangles
    return {"scene": scene, "object": scene.capitalize(), "triangles": triangles,
            "width": size, "height": size, "threads": {"setting": setting}, "median": median,
            "network": {"hit_iou": None if neural_ms is None else 0.99,
                        "false_negative_rate": 0.001, "false_positive_rate": 0.002},
            "bytes": {"model": 10_000, "mesh": mesh, "bvh": {n: 50 * triangles
                                                              for n in baselines},
                      "model_over_mesh_and_bvh": {n: 10_000 / (mesh + 50 * triangles)
                                                  for n in baselines}}}


def power_law_results(neural_ms, scale, power, size=256, setting=2):
    """The Suzanne sweep (levels 2 to 6) with each classical pose scale * T^power ms and the
    neural pose neural_ms at every mesh, and the bunny."""
    baselines = core("studies.baselines").BASELINES
    sizes = {f"suzanne-{level}": 968 * 4 ** level for level in range(2, 7)}
    sizes["bunny"] = 69_451
    return [fake_result(scene, t, neural_ms, {b: scale[b] * t ** power[b] for b in baselines},
                        size, setting) for scene, t in sizes.items()]


def test_the_crossover_is_exact_where_both_poses_follow_power_laws(extension):
    """Classical pose a T^p against a constant neural pose N cross at T* = (N / a)^(1/p),
    which log-log interpolation between the sweep's meshes finds exactly."""
    cross = core("studies.side_by_side_crossover")
    scale = {"bvhtree": 2e-2, "warp": 1e-4, "embree_refit": 1e-4, "embree_rebuild": 1e-3}
    power = {"bvhtree": 1.0, "warp": 1.0, "embree_refit": 0.9, "embree_rebuild": 0.8}
    neural = 40.0
    data = cross.crossover(power_law_results(neural, scale, power))
    expected = {name: (neural / scale[name]) ** (1 / power[name]) for name in scale}
    rows = {row["baseline"]: row for row in data["rows"]}
    for name in ("warp", "embree_refit", "embree_rebuild"):
        assert 15_488 < expected[name] < 3_964_928                    # inside the sweep
        assert rows[name]["triangles"] == pytest.approx(expected[name], rel=1e-9)
        assert rows[name]["text"] == f"neural cheaper from {expected[name]:,.0f}"
        assert len(rows[name]["points"]) == 5
        bunny = rows[name]["others"][0]
        assert bunny["object"] == "Bunny" and bunny["ratio"] == pytest.approx(
            neural / (scale[name] * 69_451 ** power[name]))
    # the BVHTree loop costs more than the neural pose from the smallest mesh on
    assert rows["bvhtree"]["triangles"] is None
    assert rows["bvhtree"]["text"] == "neural cheaper on the whole sweep (15,488 and up)"
    assert [mesh["triangles"] for mesh in data["bytes"]] == sorted(
        [968 * 4 ** level for level in range(2, 7)] + [69_451])


def test_crossover_without_a_crossing_with_two_and_with_withheld_speeds(extension):
    cross = core("studies.side_by_side_crossover")
    # neural / classical: 2 at 10, 0.5 at 100, 2 at 1000: down through 1 at sqrt(10) * 10,
    # then up through it at sqrt(10) * 100 (log-linear between the points)
    found = cross.crossings([(10, 2.0, 1.0), (100, 1.0, 2.0), (1000, 4.0, 2.0)])
    assert [way for _, way in found] == [1, -1]
    assert [t for t, _ in found] == pytest.approx([10 * 10 ** 0.5, 100 * 10 ** 0.5])
    # a ratio of exactly 1 at a point is the crossing itself
    assert cross.crossings([(10, 2.0, 1.0), (100, 1.0, 1.0), (1000, 1.0, 3.0)]) == [(100, 1)]
    baselines = core("studies.baselines").BASELINES
    scale, power = dict.fromkeys(baselines, 1e-9), dict.fromkeys(baselines, 1.0)
    rows = cross.crossover(power_law_results(40.0, scale, power))["rows"]
    assert all(row["triangles"] is None and row["text"]
               == "classical cheaper on the whole sweep (up to 3,964,928)" for row in rows)
    withheld = power_law_results(None, scale, power)
    rows = cross.crossover(withheld)["rows"]
    assert all(row["text"].startswith("n/a (no neural speed on Suzanne-2, Suzanne-3")
               for row in rows)
    assert all(other["ratio"] is None for row in rows for other in row["others"])


def test_the_crossover_sweeps_the_scenes_it_is_named(extension):
    """Another mesh's levels (the dense character's) are the sweep when named; Suzanne is
    then one of the other meshes, reported at its size."""
    cross = core("studies.side_by_side_crossover")
    baselines = core("studies.baselines").BASELINES
    scale = dict.fromkeys(baselines, 1e-4)
    results = [fake_result(f"character-{level}", 5856 * 4 ** level, 40.0,
                           {b: scale[b] * (5856 * 4 ** level) for b in baselines})
               for level in (2, 3, 4)]
    results.append(fake_result("suzanne-3", 61_952, 40.0, dict.fromkeys(baselines, 6.2)))
    rows = cross.crossover(results, sweep="character-")["rows"]
    for row in rows:
        assert [p["triangles"] for p in row["points"]] == [93_696, 374_784, 1_499_136]
        assert row["triangles"] == pytest.approx(400_000, rel=1e-9)
        assert [o["object"] for o in row["others"]] == ["Suzanne-3"]
    lone = cross.crossover(results[:1], sweep="character-")["rows"][0]
    assert lone["text"] == "n/a (fewer than two meshes in the sweep)"
    markdown = "\n".join(cross.crossover_markdown({"rows": rows, "bytes": []}, results,
                                                   sweep="the character's levels"))
    assert "interpolated on the character's levels in log-log" in markdown


def test_crossover_markdown_and_plot(extension, tmp_path):
    cross = core("studies.side_by_side_crossover")
    plots = core("studies.side_by_side_report")
    baselines = core("studies.baselines").BASELINES
    scale, power = dict.fromkeys(baselines, 1e-4), dict.fromkeys(baselines, 1.0)
    results = [r for size, setting in ((256, 2), (64, 2), (256, 1), (64, 1))
               for r in power_law_results(40.0 if size == 256 else 8.0, scale, power, size,
                                          setting)]
    data = cross.crossover(results)
    assert [(row["width"], row["threads"]) for row in data["rows"][::len(baselines)]] == [
        (256, 2), (256, 1), (64, 2), (64, 1)]
    text = "\n".join(cross.crossover_markdown(data, results, "python batch.py -- z",
                                              None, "crossover.png"))
    assert text.startswith("Command: `python batch.py -- z`")
    heads = "| baseline | 256x256, 2 thread setting | 256x256, 1 thread setting | 64x64, 2 "
    assert heads in text and "| Warp refit | **neural cheaper from 400,000**; Bunny " in text
    assert "| Suzanne-2 (15,488) | 256x256, 2 | 40.0 | 1.5 |" in text
    assert "0.9900, 0.1 % / 0.2 %" in text
    assert "| Bunny (69,451) | 10,000 | 1,666,824 |" in text
    assert "![pose totals and bytes against triangles](crossover.png)" in text
    path = plots.write_crossover_plot(data, results, tmp_path / "crossover.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 20_000


@pytest.fixture(scope="module")
def timed(extension, tmp_path_factory):
    """compare_paths with secondary rays on the lattice demo's Suzanne at R 8, 2 unseen
    poses, 16x16 rays, one repeat, with the oracle network as the model."""
    side = core("studies.side_by_side")
    obj, captured = lattice_capture(2)
    model = stand_in_model(OracleNetwork(captured.mesh, captured.grid), captured,
                           tmp_path_factory.mktemp("model") / "oracle.vdnif")
    settings = core("inference.secondary").SecondarySettings(samples=SAMPLES)
    return side.compare_paths(obj, captured, model, RAYS, RAYS, repeats=1,
                              secondary=settings)


def test_each_path_casts_its_hits_times_the_samples_and_a_shadow_ray_per_lit_face(timed):
    secondary = core("studies.side_by_side")
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
    secondary = core("studies.side_by_side")
    passes = core("passes")
    monkeypatch.setattr(secondary, "neural_occluded", lambda *args, **kwargs: (
        lambda origins, directions, reach, leaving, start_cells=None: np.ones(len(origins),
                                                                          bool)))
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
    secondary = core("studies.side_by_side")
    table = timed["secondary"]
    assert table["settings"]["samples"] == [1, SAMPLES]
    # The network's hits start their rays off by its own error, as its passes do: at R 8
    # SECONDARY_OFFSET_VOXELS of a voxel at least, above an exact hit's offset.
    voxels = core("settings").SECONDARY_OFFSET_VOXELS
    assert table["settings"]["network_offset"] >= voxels / 8 > table["settings"]["offset"]
    assert set(table["paths"]) == set(secondary.SECONDARY_PATHS)
    assert "bvhtree" in table["skipped"]
    for name, by_samples in table["paths"].items():
        primary = core("studies.side_by_side_report").pose_total(timed, name)
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
        short = core("studies.side_by_side_report").SHORT[name]
        for samples in (1, SAMPLES):
            assert f"| {short}, {samples} AO sample(s): secondary rays/s" in text
            assert f"| {short}, {samples} AO sample(s): pose total ms" in text
    assert "| where the cheaper side changes: neural / Embree refit |" in text
    assert "- BVHTree (Python loop): not timed with secondary rays" in text


def test_the_trade_point_is_exact_for_totals_linear_in_the_samples(extension):
    secondary = core("studies.side_by_side")

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
    obj, captured = lattice_capture(1)
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
    secondary = core("studies.side_by_side")
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
