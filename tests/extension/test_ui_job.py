"""The Train operator's worker, driven directly (timers never fire in the bpy module):
progress arrives through the queue, cancel stops it and keeps the last good model."""

import threading
import time

import numpy as np
import pytest
from dataset_headers import header_dict
from test_train import SMALL, sphere_shards

from vdnif_addon.model.model_file import load_model
from vdnif_addon.training import dataset
from vdnif_addon.training.header import DatasetHeader
from vdnif_addon.training.job import JobState, TrainingJob, progress_interval

# The stopping rule off: these runs take the steps they ask for (a validation every step
# would end them after a few).
OVERRIDES = dict(SMALL, batch_size=64, device="cpu", stop_patience=0)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """A dataset folder as ``dataset`` writes it, with sphere segments of four poses."""
    folder = tmp_path_factory.mktemp("data")
    [arrays] = sphere_shards(n=512, shards=1, poses=4)
    for start, stop in ((0, 2), (2, 4)):                 # two shards of two poses each
        rows = (arrays["pose"] >= start) & (arrays["pose"] < stop)
        records = {key: value[rows] for key, value in arrays.items()}
        records.update(t0=np.zeros(rows.sum(), np.float32),
                       ray=np.arange(rows.sum(), dtype=np.int32))
        header = header_dict(pose_range=(start, stop), materials=2, segments=int(rows.sum()))
        dataset.write_shard(folder, f"shard-{start}-{stop}", records,
                            DatasetHeader.from_dict(header, "test header"))
    return folder


def wait_for(job, condition, timeout=60):
    """Polls the job like the modal timer does until ``condition(state)``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        state = job.poll()
        if condition(state):
            return state
        time.sleep(0.01)
    raise AssertionError(f"job state never satisfied the condition: {job.state}")


def test_worker_reports_progress_and_writes_the_model(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=20))
    assert job.overrides["log_interval"] == progress_interval(20) == 1
    seen = []
    job.start()
    state = wait_for(job, lambda s: seen.append(s.step) or s.done)
    assert state.status == "completed", state.message
    assert max(seen) == 20 and len(set(seen)) > 2, "progress did not arrive step by step"
    assert np.isfinite(state.loss) and state.eta_s == 0 and state.samples_per_s > 0
    assert state.model == str(out) and "completed after 20 steps" in state.line()
    _, metadata = load_model(out)
    assert metadata.training.steps == 20 and metadata.object == "Ball"
    assert [p.name for p in tmp_path.iterdir()] == ["model.vdnif"], "temporary file left"


def test_a_run_the_stopping_rule_ends_writes_its_model(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    out.write_bytes(b"the last good model")
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=200, stop_patience=2))
    job.run()
    state = job.poll()
    assert state.status == "converged" and state.step < 200, state.message
    assert state.line().startswith(f"converged after {state.step} steps in ")
    _, metadata = load_model(out)
    assert metadata.training.steps == state.step and metadata.training.status == "converged"


def test_cancel_with_keep_partial_keeps_the_last_finished_step(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=100000, log_interval=1),
                      keep_partial=True)
    job.start()
    wait_for(job, lambda s: s.step >= 3)
    job.cancel()
    assert job.state.cancelling and job.state.line().endswith("cancelling")
    state = job.join(timeout=60)
    assert state.status == "cancelled" and not state.cancelling
    network, metadata = load_model(out)
    info = metadata.training
    assert info.status == "cancelled" and 3 <= info.steps < 100000
    assert state.step == info.steps and all(
        np.isfinite(p.detach().numpy()).all() for p in network.parameters())


def test_cancel_after_some_steps_keeps_the_previous_model_by_default(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    out.write_bytes(b"the last good model")
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=100000, log_interval=1))
    job.start()
    wait_for(job, lambda s: s.step >= 3)
    job.cancel()
    state = job.join(timeout=60)
    assert state.status == "cancelled" and state.model is None and state.step >= 3
    assert state.line() == (f"cancelled after {state.step} steps (partial model dropped): "
                            "the previous model is kept")
    assert out.read_bytes() == b"the last good model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.vdnif"], "partial file left"


def test_cancel_before_the_first_step_keeps_the_previous_model(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    out.write_bytes(b"the last good model")
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=50), keep_partial=True)
    job.cancel()
    job.run()                                      # synchronously, as in background mode
    state = job.poll()
    assert state.status == "cancelled" and state.model is None
    assert "previous model is kept" in state.line()
    assert out.read_bytes() == b"the last good model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.vdnif"]


def test_failure_is_reported_and_leaves_the_previous_model(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    out.write_bytes(b"the last good model")
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=10, width=0))
    job.run()
    state = job.poll()
    assert state.status == "failed" and "width" in state.message
    assert state.line() == state.message and out.read_bytes() == b"the last good model"
    missing = TrainingJob(tmp_path / "nowhere", "proposed", out, dict(OVERRIDES, steps=10))
    missing.run()
    assert "does not exist" in missing.poll().message


def test_state_line_while_running():
    state = JobState(steps=200)
    assert state.line() == "step 0/200, starting" and state.fraction == 0
    state.step, state.loss, state.eta_s = 50, 0.25, 125.4
    assert state.line() == "step 50/200, loss 0.2500, ETA 2:05" and state.fraction == 0.25


def test_worker_thread_touches_nothing_after_join(data_dir, tmp_path):
    job = TrainingJob(data_dir, "lsnif", tmp_path / "m.vdnif", dict(OVERRIDES, steps=5))
    job.start()
    job.join(timeout=60)
    assert job.state.status == "completed"
    assert not any(t.name.startswith("vdnif-train") for t in threading.enumerate())


def test_progress_shows_the_sum_of_the_task_losses_not_the_weighted_total(data_dir, tmp_path):
    """The uncertainty weighting's total holds log-variances and goes below zero; the panel
    shows the task losses' sum, which is never negative."""
    job = TrainingJob(data_dir, "proposed", tmp_path / "m.vdnif", dict(OVERRIDES, steps=20))
    job._apply("progress", {"step": 5, "total": -1.3832, "eta_s": 3.0, "samples_per_s": 1.0,
                            "losses": {"occlusion": 0.25, "distance": 0.5, "normal": 0.125}})
    assert job.state.loss == 0.875
    assert job.state.line() == "step 5/20, loss 0.8750, ETA 3 s"


def test_the_command_line_shows_the_same_loss_as_the_panel(capsys):
    """``train``'s progress line shows the task losses' sum too, never the weighted total."""
    from vdnif_addon.cli.options import report_training

    report_training({"step": 5, "steps": 20, "total": -1.3832, "eta_s": 3.0,
                     "samples_per_s": 1.0,
                     "losses": {"occlusion": 0.25, "distance": 0.5, "normal": 0.125}})
    assert capsys.readouterr().err == ("train: step 5/20, loss 0.8750 (occlusion 0.2500, "
                                       "distance 0.5000, normal 0.1250), 1 samples/s, "
                                       "ETA 3 s\n")
