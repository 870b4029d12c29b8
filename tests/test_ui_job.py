"""The Train operator's worker, driven directly (timers never fire in the bpy module):
progress arrives through the queue, cancel stops it and keeps the last good model."""

import threading
import time

import numpy as np
import pytest
from test_train import SMALL, sphere_shards

from vdnif_addon.model.model_file import load_model
from vdnif_addon.training import dataset
from vdnif_addon.training.job import JobState, TrainingJob, progress_interval

OVERRIDES = dict(SMALL, batch_size=64, device="cpu")


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """A dataset folder as ``dataset`` writes it, with sphere segments of four poses."""
    folder = tmp_path_factory.mktemp("data")
    for number, shard in enumerate(sphere_shards(n=512, poses=4)):
        records = dict(shard, t0=np.zeros(len(shard["pose"]), np.float32),
                       ray=np.arange(len(shard["pose"]), dtype=np.int32))
        grid = {"origin": [0.0] * 3, "voxel_size": 0.125, "dims": [8, 8, 8], "resolution": 8,
                "extent": 1.0, "occupied_voxels": 100}
        header = {"object": "Ball", "mode": "armature", "object_size": 1.0, "grid": grid,
                  "voxel_size": 0.125, "heads": {"albedo": True, "material_count": 2},
                  "albedo_table": [[0.5, 0.5, 0.5]] * 2,
                  "poses": [{"frame": float(p)} for p in range(4)]}
        dataset.write_shard(folder, f"shard-{number}", records, header)
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


def test_cancel_stops_the_worker_and_keeps_the_last_finished_step(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=100000, log_interval=1))
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


def test_cancel_before_the_first_step_keeps_the_previous_model(data_dir, tmp_path):
    out = tmp_path / "model.vdnif"
    out.write_bytes(b"the last good model")
    job = TrainingJob(data_dir, "proposed", out, dict(OVERRIDES, steps=50))
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
