import dataclasses
import hashlib
import io
import os
import pathlib

import numpy as np
import pytest
import torch
from oracles import encoding_torch as oracle

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model import model_file
from vdnif_addon.model.model_file import load_model, model_bytes, save_model
from vdnif_addon.model.network import IntersectionNetwork, readout
from vdnif_addon.settings import Heads, NetworkConfig

GOLDEN = pathlib.Path(__file__).resolve().parent / "golden"

CONFIG = NetworkConfig(
    levels=2,
    base_resolution=8,
    log2_table_size=10,
    width=16,
    depth=2,
    heads=Heads(albedo=False, material_count=3),
)
EXTRA = {
    "grid": {"min": np.array([-1.0, -2.0, 0.5]), "voxel_size": 0.125, "resolution": (8, 8, 4)},
    "albedo_table": np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]],
                             dtype=np.float32),
    "materials": ["skin", "cloth", "metal"],
    "occupied": np.array([True, False, True]),
}


@pytest.fixture
def network():
    torch.manual_seed(0)
    return IntersectionNetwork(CONFIG)


@pytest.fixture
def saved(tmp_path, network):
    path = tmp_path / "model.vdnif"
    save_model(
        path, network, CONFIG, {"steps": 12, "loss": np.float32(0.5), "val_poses": [1, 4]}, EXTRA
    )
    return path


def test_round_trip_gives_identical_outputs_and_metadata(saved, network):
    loaded, meta = load_model(saved)
    assert not loaded.training and meta["network_config"] == CONFIG
    assert meta["format"] == "vdnif-model" and meta["version"] == model_file.FORMAT_VERSION
    p0, p1 = torch.rand(2, 50, 3)
    with torch.no_grad():
        expected, actual = network(p0, p1), loaded(p0, p1)
    assert expected.keys() == actual.keys()
    assert all(torch.equal(expected[key], actual[key]) for key in expected)
    assert meta["train_info"] == {"steps": 12, "loss": 0.5, "val_poses": [1, 4]}
    extra = meta["extra"]
    np.testing.assert_array_equal(extra["grid"]["min"], EXTRA["grid"]["min"])
    np.testing.assert_array_equal(extra["albedo_table"], EXTRA["albedo_table"])
    np.testing.assert_array_equal(extra["occupied"], EXTRA["occupied"])
    assert extra["grid"]["resolution"] == (8, 8, 4) and extra["materials"] == EXTRA["materials"]
    assert model_bytes(saved) == os.path.getsize(saved) > 0
    assert os.stat(saved).st_mode & 0o777 == 0o644     # readable by the farm, like any file


def test_an_albedo_field_round_trips(tmp_path):
    """A network whose albedo is a field at the hit (``albedo_mode`` "hit") keeps its mode
    and the field's table and MLP: the loaded one predicts the same albedo."""
    torch.manual_seed(1)
    config = dataclasses.replace(CONFIG, heads=Heads(albedo=True), albedo_mode="hit")
    network = IntersectionNetwork(config)
    with torch.no_grad():
        network.albedo_field.grid.table.normal_()
    path = tmp_path / "field.vdnif"
    save_model(path, network, config, {}, EXTRA)
    loaded, meta = load_model(path)
    assert meta["network_config"].albedo_mode == "hit" and loaded.albedo_field is not None
    p0, p1 = torch.rand(2, 50, 3)
    rest_len = torch.rand(50) * 0.1
    expected = network.predict(p0, p1, rest_len, 0.1)["albedo"]
    assert torch.equal(loaded.predict(p0, p1, rest_len, 0.1)["albedo"], expected)


def test_files_written_before_the_albedo_field_keep_their_albedo_head(tmp_path):
    """A stored config without ``albedo_mode`` (files written before it existed) loads as
    the head over the segment it was trained with, whatever today's default."""
    torch.manual_seed(2)
    config = dataclasses.replace(CONFIG, heads=Heads(albedo=True), albedo_mode="segment")
    network = IntersectionNetwork(config)
    path = tmp_path / "old.vdnif"
    save_model(path, network, config, {}, EXTRA)
    archive = torch.load(path, weights_only=True)
    inner = torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), weights_only=True)
    del inner["network_config"]["albedo_mode"]
    buffer = io.BytesIO()
    torch.save(inner, buffer)
    data = buffer.getvalue()
    archive["payload"] = torch.frombuffer(bytearray(data), dtype=torch.uint8)
    archive["sha256"] = hashlib.sha256(data).hexdigest()
    torch.save(archive, path)
    loaded, meta = load_model(path)
    assert meta["network_config"].albedo_mode == "segment" and loaded.albedo_field is None
    p0, p1 = torch.rand(2, 50, 3)
    rest_len = torch.rand(50) * 0.1
    assert torch.equal(loaded.predict(p0, p1, rest_len, 0.1)["albedo"],
                       network.predict(p0, p1, rest_len, 0.1)["albedo"])


def test_write_is_atomic_and_leaves_no_temporary_files(tmp_path, saved, network, monkeypatch):
    assert os.listdir(tmp_path) == ["model.vdnif"]
    good = saved.read_bytes()
    real_save = torch.save

    def failing_save(obj, target, *args, **kwargs):
        if isinstance(target, io.BytesIO):
            return real_save(obj, target, *args, **kwargs)
        target.write(b"partial model bytes")
        raise OSError("disk full")

    monkeypatch.setattr(model_file.torch, "save", failing_save)
    with pytest.raises(VDNIFError, match="model.vdnif.*disk full"):
        save_model(saved, network, CONFIG, {}, {})
    assert saved.read_bytes() == good
    assert os.listdir(tmp_path) == ["model.vdnif"]


def test_save_rejects_mismatched_config_and_unstorable_metadata(tmp_path, network):
    with pytest.raises(VDNIFError, match="different config"):
        save_model(tmp_path / "a.vdnif", network, NetworkConfig(), {}, {})
    with pytest.raises(VDNIFError, match="extra.mesh"):
        save_model(tmp_path / "a.vdnif", network, CONFIG, {}, {"mesh": object()})
    with pytest.raises(VDNIFError, match="a.vdnif"):
        save_model(tmp_path / "missing" / "a.vdnif", network, CONFIG, {}, {})
    assert os.listdir(tmp_path) == []


def _corrupt(data):
    data = bytearray(data)
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(255 - b for b in data[middle : middle + 64])
    return bytes(data)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda good: _corrupt(good), "model.vdnif"),
        (lambda good: good[: len(good) // 2], "model.vdnif"),
        (lambda good: good[:100], "model.vdnif"),
        (lambda good: np.random.default_rng(0).bytes(4096), "model.vdnif"),
        (lambda good: b"", "model.vdnif"),
    ],
    ids=["corrupt", "truncated", "truncated-header", "random-bytes", "empty"],
)
def test_damaged_files_raise_naming_the_file(saved, make, message):
    saved.write_bytes(make(saved.read_bytes()))
    with pytest.raises(VDNIFError, match=message):
        load_model(saved)


def test_foreign_checkpoints_are_not_models(tmp_path, network):
    plain = tmp_path / "checkpoint.pt"
    torch.save({"state_dict": network.state_dict(), "epoch": 3}, plain)
    with pytest.raises(VDNIFError, match="checkpoint.pt is not a VDNIF model"):
        load_model(plain)
    pickled_module = tmp_path / "module.pt"
    torch.save(torch.nn.Linear(2, 2), pickled_module)  # unpickling it would need code execution
    with pytest.raises(VDNIFError, match="module.pt"):
        load_model(pickled_module)
    with pytest.raises(VDNIFError, match="nothing.vdnif does not exist"):
        load_model(tmp_path / "nothing.vdnif")
    with pytest.raises(VDNIFError, match="nothing.vdnif"):
        model_bytes(tmp_path / "nothing.vdnif")


def test_newer_format_version_is_refused(saved):
    archive = torch.load(saved, weights_only=True)
    archive["version"] = model_file.FORMAT_VERSION + 1
    torch.save(archive, saved)
    with pytest.raises(
        VDNIFError, match=f"model.vdnif has format version {model_file.FORMAT_VERSION + 1}.*update"
    ):
        load_model(saved)


def _stored_state(path):
    """The state dict exactly as the file holds it (no migration)."""
    archive = torch.load(path, weights_only=True)
    inner = torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), weights_only=True)
    return archive["version"], inner["state_dict"]


@pytest.mark.parametrize("name", ["arm-train.vdnif", "arm-render-model.vdnif"])
def test_format_1_files_load_and_predict_what_the_torch_encoder_predicted(name):
    """Golden files written before the kernel (format 1, table feature-major (Fd, rows)) load
    with the table transposed, and predict what the torch encoder predicts with their table."""
    path = GOLDEN / name
    version, stored = _stored_state(path)
    assert version == 1 and model_file.FORMAT_VERSION == 2
    network, meta = load_model(path)
    assert meta["version"] == 1
    old_table = stored["encoder.grid.table"]
    assert old_table.shape[0] == network.config.feature_dim
    assert torch.equal(network.encoder.grid.table, old_table.t())

    reference = oracle.from_product(network.encoder, correctly_rounded=True)
    assert torch.equal(reference.grid.table, old_table)
    generator = torch.Generator().manual_seed(0)
    p0 = torch.rand(4000, 3, generator=generator)
    p1 = (p0 + 0.05 * torch.randn(4000, 3, generator=generator)).clamp(0, 1)
    length = (p1 - p0).norm(dim=1)
    predicted = network.predict(p0, p1, length, 0.05)
    with torch.no_grad():
        expected = readout(network.heads(reference(p0, p1)), network.config.distance_mode,
                           0.05, length)
    assert predicted.keys() == expected.keys()
    for key in expected:
        torch.testing.assert_close(predicted[key], expected[key], rtol=1e-5, atol=1e-6)
    assert predicted["hit_probability"].std() > 1e-3  # varies from segment to segment


def test_saving_writes_the_current_format_with_a_row_major_table(saved, network):
    version, stored = _stored_state(saved)
    assert version == model_file.FORMAT_VERSION == 2
    assert torch.equal(stored["encoder.grid.table"], network.encoder.grid.table)
    assert stored["encoder.grid.table"].shape == (network.encoder.grid.table.shape[0], 3)


def test_the_stored_occlusion_threshold_decides_the_predicted_hits(tmp_path, network):
    """A calibrated threshold in ``extra`` comes back on the network and ``predict`` applies
    it (the renderer's call); a file without one, such as the format-1 golden, gets 0.5."""
    path = tmp_path / "calibrated.vdnif"
    save_model(path, network, CONFIG, {}, dict(EXTRA, occlusion_threshold=0.62))
    loaded, _ = load_model(path)
    assert loaded.occlusion_threshold == pytest.approx(0.62)
    p0, p1 = torch.rand(2, 400, 3)
    rest_len = (p1 - p0).norm(dim=1)
    probability = torch.sigmoid(loaded(p0, p1)["occlusion"])
    predicted = loaded.predict(p0, p1, rest_len, 0.125)["hit"]
    assert torch.equal(predicted, probability > 0.62)
    golden, _ = load_model(GOLDEN / "arm-train.vdnif")
    assert golden.occlusion_threshold == 0.5


def test_the_stored_candidate_threshold_decides_the_candidates(tmp_path, network):
    """A candidate threshold in ``extra`` comes back and ``predict`` marks the segments above
    it; a file without one places hits as before (candidates are the hits), and one above
    the occlusion threshold is taken at that threshold."""
    p0, p1 = torch.rand(2, 400, 3)
    rest_len = (p1 - p0).norm(dim=1)
    probability = torch.sigmoid(network(p0, p1)["occlusion"])
    for extra, expected in ((dict(occlusion_threshold=0.62, candidate_threshold=0.05), 0.05),
                            (dict(occlusion_threshold=0.62), 0.62),
                            (dict(occlusion_threshold=0.4, candidate_threshold=0.7), 0.4)):
        path = tmp_path / "candidate.vdnif"
        save_model(path, network, CONFIG, {}, dict(EXTRA, **extra))
        loaded, _ = load_model(path)
        assert loaded.candidate_threshold == pytest.approx(expected)
        predicted = loaded.predict(p0, p1, rest_len, 0.125)
        assert torch.equal(predicted["candidate"], probability > expected)
        assert torch.equal(predicted["hit"], probability > extra["occlusion_threshold"])
