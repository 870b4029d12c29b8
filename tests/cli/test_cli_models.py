"""The commands that load a trained model (render, evaluate, side-by-side) run through the
command line with a small model, on ``--device cpu`` and ``auto``: a device resolved by one
layer and handed to the next must be accepted there."""

import json

import pytest

pytestmark = pytest.mark.slow

SMALL_TRAIN = ("--resolution", "8", "--poses", "2", "--rays-per-pose", "1024", "--steps", "40",
               "--batch", "1024", "--levels", "2", "--log2-table-size", "12", "--width", "16",
               "--depth", "1")
VIEW = ("--width", "8", "--height", "8")


@pytest.fixture(scope="module")
def small_model(extension, tmp_path_factory):
    """A lattice-scene model trained for a few steps through ``train``."""
    import importlib

    cli = importlib.import_module(f"{extension.__name__}.vdnif_addon.cli")
    folder = tmp_path_factory.mktemp("model")
    model = folder / "lattice.vdnif"
    code = cli.main(["train", "--scene", "lattice", *SMALL_TRAIN, "--device", "cpu",
                     "--out", str(model)])
    assert code == 0 and model.is_file()
    return cli, model


@pytest.mark.parametrize("device", ["cpu", "auto"])
def test_render_evaluate_and_side_by_side_take_a_model(small_model, tmp_path, capsys, device):
    cli, model = small_model
    assert cli.main(["render", "--model", str(model), "--scene", "lattice", *VIEW,
                     "--device", device, "--out", str(tmp_path / "render")]) == 0
    assert (tmp_path / "render" / "render.json").is_file()
    assert cli.main(["evaluate", "--model", str(model), "--scene", "lattice", "--poses", "1",
                     *VIEW, "--device", device, "--out", str(tmp_path / "evaluate"),
                     "--json", str(tmp_path / "evaluate.json")]) == 0
    evaluated = json.loads((tmp_path / "evaluate.json").read_text())
    assert evaluated["vs_true"]["false_negative_rate"] is not None
    assert evaluated["pose_set"] == "test"          # the reported set unless asked otherwise
    assert cli.main(["side-by-side", "--scene", "lattice", "--model", f"lattice={model}",
                     "--poses", "1", "--repeats", "1", *VIEW, "--device", device,
                     "--json", str(tmp_path / "sbs.json")]) == 0
    result = json.loads((tmp_path / "sbs.json").read_text())["results"][0]
    assert result["scene"] == "lattice" and "neural" in json.dumps(result)
    printed = capsys.readouterr()
    assert "error" not in printed.err
    assert "verdict against the mesh: " in printed.out
    for name in ("passes.exr", "true-passes.exr", "figure-vs-true.png"):
        assert (tmp_path / "evaluate" / name).is_file(), name


def test_no_printed_speed_includes_compiling_the_kernels(small_model, tmp_path, capsys,
                                                         monkeypatch):
    """A first run compiles the kernels: render and evaluate load them all before their
    clocks start and say the time apart. Warp's loading is made to take 1 s per module (as
    a compile would; the kernels forgotten as loaded before each command): inside the
    render's clock it would hold the 8x8 image's 64 rays under 64 rays/s."""
    import importlib
    import time

    import warp as wp

    cli, model = small_model
    runtime = importlib.import_module(f"{cli.__name__.rpartition('.')[0]}.kernels.runtime")
    load_module, loads = wp.load_module, []

    def compile_slowly(name, device):
        loads.append(name)
        time.sleep(1.0)
        load_module(name, device=device)

    monkeypatch.setattr(wp, "load_module", compile_slowly)
    monkeypatch.setattr(runtime, "_loaded", set())
    assert cli.main(["render", "--model", str(model), "--scene", "lattice", *VIEW,
                     "--device", "cpu", "--out", str(tmp_path / "render")]) == 0
    rendered = json.loads((tmp_path / "render" / "render.json").read_text())
    # every module loaded once, all of them before the clock (the time of all the loads)
    modules = len(loads)
    assert modules >= 7 and len(set(loads)) == modules
    assert rendered["kernels_s"] >= modules and rendered["rays_per_s"] > 64
    printed = capsys.readouterr()
    assert f"kernels ready for cpu in {rendered['kernels_s']:.1f} s" in printed.err
    assert f"{rendered['rays_per_s']:,.0f} rays/s" in printed.out
    monkeypatch.setattr(runtime, "_loaded", set())
    assert cli.main(["evaluate", "--model", str(model), "--scene", "lattice", "--poses", "1",
                     *VIEW, "--device", "cpu", "--json", str(tmp_path / "evaluate.json")]) == 0
    timings = json.loads((tmp_path / "evaluate.json").read_text())["timings"]
    assert len(loads) == 2 * modules and timings["kernels_s"] >= modules


def test_evaluate_reports_on_the_test_poses_unless_asked_for_the_development_ones(
        small_model, monkeypatch, tmp_path):
    """``--pose-set`` reaches the capture: the test poses by default, the development poses
    (another seed, for choices such as time-to-clean's) when asked for, and they differ."""
    import importlib

    cli, model = small_model
    steps = importlib.import_module(cli.__name__.rpartition(".")[0] + ".blender.steps")
    original, seen = steps.model_capture, []

    def spy(*args, **kwargs):
        captured = original(*args, **kwargs)
        seen.append((kwargs["pose_set"], captured.poses))
        return captured

    monkeypatch.setattr(steps, "model_capture", spy)
    for chosen in ((), ("--pose-set", "development"), ("--pose-set", "test")):
        assert cli.main(["evaluate", "--model", str(model), "--scene", "lattice", "--poses",
                         "2", *VIEW, "--device", "cpu", *chosen]) == 0
    assert [name for name, _ in seen] == ["test", "development", "test"]
    assert seen[0][1] == seen[2][1] and seen[0][1] != seen[1][1]


def test_bfloat16_runs_the_network_in_bfloat16_where_the_device_has_it(small_model, tmp_path,
                                                                       capsys, monkeypatch):
    """``--precision bfloat16`` reaches the network: evaluate and side-by-side say so in their
    JSON (``test_network`` holds its arithmetic to an oracle); on a device without bfloat16
    instructions (made so here, as it is made to have them first) the command refuses it
    in one line and exits non-zero, writing nothing."""
    import importlib

    cli, model = small_model
    runtime = importlib.import_module(f"{cli.__name__.rpartition('.')[0]}.kernels.runtime")
    monkeypatch.setattr(runtime, "bfloat16_native", lambda device: True)
    for precision in ("float32", "bfloat16"):
        path = tmp_path / f"{precision}.json"
        assert cli.main(["evaluate", "--model", str(model), "--scene", "lattice", "--poses",
                         "1", *VIEW, "--device", "cpu", "--precision", precision, "--json",
                         str(path)]) == 0
        assert json.loads(path.read_text())["precision"] == precision
    assert cli.main(["side-by-side", "--scene", "lattice", "--model", f"lattice={model}",
                     "--poses", "1", "--repeats", "1", *VIEW, "--precision", "bfloat16",
                     "--json", str(tmp_path / "sbs.json")]) == 0
    result = json.loads((tmp_path / "sbs.json").read_text())["results"][0]
    assert result["network"]["precision"] == "bfloat16"
    assert "--precision bfloat16" in json.loads((tmp_path / "sbs.json").read_text())["command"]
    capsys.readouterr()
    monkeypatch.setattr(runtime, "bfloat16_native", lambda device: False)
    assert cli.main(["render", "--model", str(model), "--scene", "lattice", *VIEW,
                     "--device", "cpu", "--precision", "bfloat16",
                     "--out", str(tmp_path / "refused")]) == 1
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "has no bfloat16 instructions" in error
    assert not (tmp_path / "refused").exists()


def test_the_default_precision_is_bfloat16_only_where_the_device_has_it(small_model, tmp_path,
                                                                         monkeypatch):
    """Without ``--precision`` (auto) the network runs in bfloat16 on a device with bfloat16
    instructions and in float32 on one without (each made so here), and the report says which:
    the same rows as the explicit choices give."""
    import importlib

    cli, model = small_model
    runtime = importlib.import_module(f"{cli.__name__.rpartition('.')[0]}.kernels.runtime")
    reports = {}
    for native, chosen in ((True, ()), (False, ()), (True, ("--precision", "bfloat16")),
                           (False, ("--precision", "float32"))):
        monkeypatch.setattr(runtime, "bfloat16_native", lambda device, native=native: native)
        path = tmp_path / f"{native}-{len(chosen)}.json"
        assert cli.main(["evaluate", "--model", str(model), "--scene", "lattice", "--poses",
                         "1", *VIEW, "--device", "cpu", *chosen, "--json", str(path)]) == 0
        reports[native, bool(chosen)] = json.loads(path.read_text())
    assert reports[True, False]["precision"] == "bfloat16"
    assert reports[False, False]["precision"] == "float32"
    for native in (True, False):
        assert reports[native, False]["vs_true"] == reports[native, True]["vs_true"]
