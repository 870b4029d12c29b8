"""GPU memory on the CUDA path, checked on the CPU: the training rows stay in host memory (the
split's columns against the concatenate-then-mask oracle) and each step's batch moves to the
device ("meta" stands in for a GPU); a render's waves are
capped and split with the same passes; an out-of-memory failure of torch or Warp is one
VDNIFError line that says what to lower; a training job hands torch's cached GPU memory
back (``torch.cuda`` faked)."""

import pathlib

import numpy as np
import pytest
import torch
from oracles import split_data as oracle
from test_render import RandomNetwork, bent_ball

from vdnif_addon import memory
from vdnif_addon.errors import VDNIFError
from vdnif_addon.inference import neural_render as render
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.settings import Heads, TrainConfig
from vdnif_addon.tracing import rays
from vdnif_addon.training import fit
from vdnif_addon.training.data import Batches, split_data
from vdnif_addon.training.distributed import ProcessGroup
from vdnif_addon.training.job import TrainingJob

TORCH_OOM = ("CUDA out of memory. Tried to allocate 4.00 GiB. GPU 0 has a total capacity of "
             "7.79 GiB of which 3.44 MiB is free. Including non-PyTorch memory, this process "
             "has 7.78 GiB memory in use.\nIf reserved but unallocated memory is large try "
             "setting PYTORCH_CUDA_ALLOC_CONF=expandable_segments:True")
WARP_OOM = "Failed to allocate 17179869184 bytes on device 'cuda:0'"


def shards(rows=400, poses=4, seed=0):
    """Two shards of random rows that satisfy the data contract (two materials, albedo)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(2):
        hit = rng.random(rows) < 0.3
        out.append({
            "p0": rng.random((rows, 3), np.float32), "p1": rng.random((rows, 3), np.float32),
            "seg_len": rng.random(rows, np.float32), "rest_len": rng.random(rows, np.float32),
            "t0": rng.random(rows, np.float32), "hit": hit.astype(np.uint8),
            "hit_frac": rng.random(rows, np.float32), "normal": rng.random((rows, 3), np.float32),
            "albedo": rng.random((rows, 3), np.float32),
            "material": rng.integers(0, 2, rows).astype(np.int16),
            "pose": rng.integers(0, poses, rows).astype(np.int32),
            "ray": np.arange(rows, dtype=np.int32)})
    return out


@pytest.mark.parametrize("poses, heads, view_from", [
    (4, Heads(albedo=True, material_count=2), None), (1, Heads(), None),
    (3, Heads(material_count=2), None), (4, Heads(material_count=2), 320), (1, Heads(), 320)])
def test_the_split_is_the_concatenated_rows_masked(poses, heads, view_from):
    """Each column written once, shard by shard, holds the rows, order and dtype of the
    shards concatenated and then masked by the held-out poses (or rays, with one pose); rays
    numbered ``view_from`` and up (a calibration view's) are never training rows, and the
    held-out ones are kept apart from the validation rows."""
    config = TrainConfig(batch_size=64, val_fraction=0.25, device="cpu")
    rows, held_out, view, val_poses = split_data(shards(poses=poses), config, heads,
                                                 torch.device("cpu"), ProcessGroup(),
                                                 view_from)
    expected = oracle.split_data(shards(poses=poses), config, heads, ProcessGroup(), view_from)
    assert val_poses == expected[3] and (val_poses == []) == (poses == 1)
    for got, want in zip((rows, held_out, view), expected[:3]):
        assert got.keys() == want.keys()
        for key in want:
            assert got[key].dtype == want[key].dtype and torch.equal(got[key], want[key]), key
    assert 0 < len(held_out["p0"]) < len(rows["p0"])
    assert (len(view["p0"]) > 0) == (view_from is not None)
    if view_from is not None:
        assert (view["ray"] >= view_from).all() and (held_out["ray"] < view_from).all()


def test_training_rows_stay_on_the_host_and_each_batch_moves_to_the_device():
    """Only the held-out rows (validation evaluates them in chunks) go to the device; the
    training rows stay in host memory, and every step's batch is moved there."""
    config = TrainConfig(val_fraction=0.25, batch_size=64, val_segments=30, device="cpu")
    heads = Heads(albedo=True, material_count=2)
    rows, held_out, _, poses = split_data(shards(), config, heads, torch.device("meta"),
                                       ProcessGroup())
    assert poses and {value.device.type for value in rows.values()} == {"cpu"}
    assert {value.device.type for value in held_out.values()} == {"meta"}
    assert rows.device == torch.device("meta") and "ray" not in rows and "ray" in held_out
    batches = Batches(rows, config.batch_size, seed=3)
    assert {value.device.type for value in rows.values()} == {"cpu"}, "moved up front"
    for _ in range(3):
        batch = batches.next()
        assert batch.keys() == rows.keys()
        assert all(value.device.type == "meta" and value.shape[0] == 64
                   for value in batch.values())
    probe = batches.subset(held_out, 30)
    assert all(value.device.type == "meta" and value.shape[0] == 30 for value in probe.values())
    # On the CPU the batches are the rows the host generator draws, as before.
    rows, held_out, _, _ = split_data(shards(), config, heads, torch.device("cpu"), ProcessGroup())
    batches, generator = Batches(rows, 64, seed=3), torch.Generator().manual_seed(3)
    order = torch.randperm(held_out["p0"].shape[0], generator=generator)[:30]
    torch.testing.assert_close(batches.subset(held_out, 30)["p0"], held_out["p0"][order])
    index = torch.randint(rows["p0"].shape[0], (64,), generator=generator)
    batch = batches.next()
    for key, value in rows.items():
        assert torch.equal(batch[key], value[index]), key


@pytest.mark.parametrize("share, on_device", [(memory.DEVICE_ROWS_SHARE, True),
                                             (1.01 * memory.DEVICE_ROWS_SHARE, False)])
def test_training_rows_move_to_a_device_with_room_for_them(monkeypatch, share, on_device):
    """Rows that take at most ``DEVICE_ROWS_SHARE`` of the device's free memory move there
    (every field, none left in host memory) and each batch is gathered there; more stay in
    host memory. A device whose free memory is not known ("meta", the CPU) keeps them on the
    host (the test above)."""
    config = TrainConfig(val_fraction=0.25, batch_size=64, val_segments=30, device="cpu")
    heads = Heads(albedo=True, material_count=2)
    host, _, _, _ = split_data(shards(), config, heads, torch.device("cpu"), ProcessGroup())
    size = sum(value.numel() * value.element_size() for value in host.values())
    monkeypatch.setattr(memory, "device_free_bytes",
                        lambda device: size / share if device.type == "meta" else None)
    rows, _, _, _ = split_data(shards(), config, heads, torch.device("meta"), ProcessGroup())
    assert rows.keys() == host.keys()
    assert {value.device.type for value in rows.values()} == {"meta" if on_device else "cpu"}
    assert all(value.shape == host[key].shape and value.dtype == host[key].dtype
               for key, value in rows.items())
    batch = Batches(rows, 64, seed=3).next()
    assert all(value.device.type == "meta" and value.shape[0] == 64
               for value in batch.values())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_training_rows_on_the_gpu_give_the_host_generators_batches_cuda():
    """On a GPU with room the rows live there, and each batch is the rows of the host
    generator's draws, as in host memory."""
    config = TrainConfig(val_fraction=0.25, batch_size=64, val_segments=30, device="cuda")
    heads = Heads(albedo=True, material_count=2)
    rows, _, _, _ = split_data(shards(), config, heads, torch.device("cuda"), ProcessGroup())
    host, _, _, _ = split_data(shards(), config, heads, torch.device("cpu"), ProcessGroup())
    assert {value.device.type for value in rows.values()} == {"cuda"}
    batches, generator = Batches(rows, 64, seed=3), torch.Generator().manual_seed(3)
    for _ in range(3):
        index = torch.randint(host["p0"].shape[0], (64,), generator=generator)
        batch = batches.next()
        for key, value in host.items():
            assert torch.equal(batch[key].cpu(), value[index]), key


def test_batches_gathered_ahead_are_the_generators_draws_in_order():
    """The next batch's host rows are gathered on another thread while a step computes;
    batch after batch they are still the rows of the generator's draws, in order."""
    import threading

    config = TrainConfig(val_fraction=0.25, batch_size=64, val_segments=30, device="cpu")
    rows, held_out, _, _ = split_data(shards(), config, Heads(albedo=True, material_count=2),
                                   torch.device("cpu"), ProcessGroup())
    gathered_on = []

    class Recording(Batches):
        def _gather(self, index):
            gathered_on.append(threading.get_ident())
            return super()._gather(index)

    batches, generator = Recording(rows, 64, seed=3), torch.Generator().manual_seed(3)
    order = torch.randperm(held_out["p0"].shape[0], generator=generator)[:30]
    torch.testing.assert_close(batches.subset(held_out, 30)["p0"], held_out["p0"][order])
    for _ in range(5):
        index = torch.randint(rows["p0"].shape[0], (64,), generator=generator)
        batch = batches.next()
        for key, value in rows.items():
            assert torch.equal(batch[key], value[index]), key
    batches._ahead.result()     # the sixth batch's gather, submitted by the fifth next()
    assert len(gathered_on) == 6 and threading.get_ident() not in gathered_on


@pytest.mark.parametrize("cap", [100, 300])
def test_a_capped_wave_splits_the_render_with_the_same_passes(monkeypatch, cap):
    """A wave over the cap walks part of the rays (the first waves: 1500 rays, a few hundred
    segments) or fewer segments per ray (the last ones): a buffer at the cap, none over it,
    the same passes. One lane, so that the waves do not depend on the cores."""
    mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([-0.5, 0.4, 1]) /
                                          np.linalg.norm([-0.5, 0.4, 1]), 40, 30)
    rng = np.random.default_rng(5)
    origins = np.concatenate([origins, rng.uniform(bend.min(0), bend.max(0), (300, 3))])
    directions = np.concatenate([directions, rng.normal(size=(300, 3))])
    assert len(origins) == 1500
    table = np.array([[0.2, 0.4, 0.6], [0.9, 0.1, 0.0]], np.float32)
    network = RandomNetwork(albedo=True)
    whole, whole_stats = render.neural_passes(network, grid, table, cells, origins, directions,
                                              lanes=1)
    capacities = []
    made = render.segment_buffer
    monkeypatch.setattr(render, "segment_buffer",
                        lambda capacity, device: capacities.append(capacity) or made(capacity,
                                                                                     device))
    split, stats = render.neural_passes(network, grid, table, cells, origins, directions,
                                        lanes=1, max_wave_segments=cap)
    assert max(capacities) == cap, "no wave was capped, or one passed the cap"
    assert stats["waves"] >= whole_stats["waves"]
    assert whole.hit.sum() > 300 and stats["truncated"] == 0
    for name in ("hit", "distance", "normal", "albedo", "material"):
        np.testing.assert_array_equal(getattr(split, name), getattr(whole, name), name)


def test_out_of_memory_is_one_line_that_says_what_to_lower():
    for failure, detail in ((torch.cuda.OutOfMemoryError(TORCH_OOM),
                             "CUDA out of memory. Tried to allocate 4.00 GiB"),
                            (RuntimeError(WARP_OOM), WARP_OOM)):
        with pytest.raises(VDNIFError) as raised, memory.out_of_memory("training",
                                                                       memory.TRAINING_ADVICE):
            raise failure
        message = str(raised.value)
        assert message == f"training ran out of memory ({detail}): {memory.TRAINING_ADVICE}"
        assert "\n" not in message and "batch size" in message
    with pytest.raises(RuntimeError, match="unrelated"), memory.out_of_memory("x", "y"):
        raise RuntimeError("unrelated")


class OutOfMemoryNetwork(RandomNetwork):
    def predict(self, *args):
        raise torch.cuda.OutOfMemoryError(TORCH_OOM)


def test_a_render_out_of_memory_says_to_lower_the_image_size(monkeypatch):
    """torch's failure in the network and Warp's in a wave's buffer."""
    mesh, grid, bend = bent_ball()
    cells = DeviceCells(grid, corners=bend)
    origins, directions = rays.orbit_rays(bend.min(0), bend.max(0), np.array([0.0, 0.0, 1.0]),
                                          8, 8)
    table = np.ones((2, 3), np.float32)
    with pytest.raises(VDNIFError, match=r"^rendering ran out of memory \(CUDA out of memory\. "
                                         r"Tried to allocate 4\.00 GiB\): lower the image size"):
        render.neural_passes(OutOfMemoryNetwork(), grid, table, cells, origins, directions)

    def no_buffer(capacity, device):
        raise RuntimeError(WARP_OOM)

    monkeypatch.setattr(render, "segment_buffer", no_buffer)
    with pytest.raises(VDNIFError, match="^rendering ran out of memory .*lower the image size"):
        render.neural_passes(RandomNetwork(), grid, table, cells, origins, directions)


def test_a_training_job_hands_back_cached_gpu_memory(monkeypatch, tmp_path):
    """A job that ran on CUDA (faked) empties torch's cache when it ends, failed or not; its
    out-of-memory failure is one line naming the batch size."""
    emptied = []
    monkeypatch.setattr(torch.cuda, "is_initialized", lambda: True)
    monkeypatch.setattr(torch.cuda, "empty_cache", lambda: emptied.append(True))

    def failing(*args, **kwargs):
        raise torch.cuda.OutOfMemoryError(TORCH_OOM)

    monkeypatch.setattr(fit, "train", failing)
    golden = pathlib.Path(__file__).resolve().parents[1] / "golden" / "arm-dataset"
    job = TrainingJob(golden, "proposed", tmp_path / "model.vdnif", {"steps": 10})
    job.run()
    state = job.poll()
    assert state.status == "failed" and emptied == [True]
    assert "\n" not in state.message and state.message.startswith(
        "training ran out of memory (CUDA out of memory. Tried to allocate 4.00 GiB): lower "
        "the batch size")

    def finishing(data_dir, variant, out, overrides, progress, cancel):
        out.write_bytes(b"model")
        result = type("Result", (), {"steps": 10, "status": "completed"})()
        return result, {"train": {"steps": 10, "seconds": 1.0}}

    monkeypatch.setattr(fit, "fit_model", finishing)
    job = TrainingJob(tmp_path, "proposed", tmp_path / "model.vdnif", {"steps": 10})
    job.run()
    assert job.poll().status == "completed" and emptied == [True, True]
    assert (tmp_path / "model.vdnif").read_bytes() == b"model"


def test_training_out_of_memory_is_one_line_from_the_command_line_and_the_panel(
        monkeypatch, tmp_path):
    """``fit_model``, which the train command, the demo and the panel's job all call, turns a
    GPU allocation failure inside training into the one-line error."""
    def fail(*args, **kwargs):
        raise torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")

    monkeypatch.setattr(fit, "train", fail)
    golden = pathlib.Path(__file__).resolve().parents[1] / "golden" / "arm-dataset"
    with pytest.raises(VDNIFError, match="training ran out of memory") as raised:
        fit.fit_model(golden, "proposed", tmp_path / "m.vdnif", {"steps": 1})
    assert memory.TRAINING_ADVICE in str(raised.value) and "\n" not in str(raised.value)
    assert not (tmp_path / "m.vdnif").exists()
