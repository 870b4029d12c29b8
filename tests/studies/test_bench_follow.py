"""The sweep trains its points as the product would: a resolution's dataset follows the
corners' way measured for it (``steps.training_capture``), and every point is evaluated
following as its own model file says. A slab in a tightly fitted lattice follows the
evaluated surface (the bench's arm keeps the copies: ``test_bench``)."""

from thin_lattice import thin_lattice_slab

SURFACE = "evaluated surface"


def test_a_thin_lattice_point_trains_and_is_evaluated_with_the_binding(empty_scene, core,
                                                                      tmp_path, monkeypatch):
    bench = core("studies.bench")
    quick = bench.SIZES["quick"]
    size = dict(quick, rays_per_pose=64, eval_poses=1, width=16, height=16, speed_rounds=1,
                overrides=dict(batch_size=256),
                convergence=dict(quick["convergence"], validate_every=2, max_steps=2))
    points = [dict(quick["base"], resolution=16, log2_table_size=10)]
    slab = thin_lattice_slab()
    spec = core("pose_sets").PoseSpec(count=2)
    work, scratch = tmp_path / "work", tmp_path / "scratch"
    work.mkdir()
    scratch.mkdir()
    assert bench._train_points(slab, spec, size, points, [0], work, scratch, "cpu",
                               None) == []
    header = core("training.dataset").read_dataset(scratch / "r16")[0].header
    assert header.corners_follow == SURFACE
    _, metadata = core("model.model_file").load_model(work / "point-0.vdnif")
    assert metadata.corners_follow == SURFACE
    evaluated, real = [], bench.evaluation_poses
    monkeypatch.setattr(bench, "evaluation_poses", lambda *args, **kwargs: evaluated.append(
        real(*args, **kwargs)) or evaluated[-1])
    [row] = bench._evaluate_points(slab, spec, size, points, work, "cpu")
    assert [captured.corners_follow for captured in evaluated] == [SURFACE]
    assert row["resolution"] == 16
