import dataclasses
import errno
import hashlib
import io
import os
import pathlib

import numpy as np
import pytest
import torch
from model_metadata import metadata_dict
from oracles import encoding_torch as oracle

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model import metadata as metadata_module
from vdnif_addon.model import model_file
from vdnif_addon.model.metadata import FORMAT_VERSION, ModelMetadata, Thresholds
from vdnif_addon.model.model_file import load_model, model_bytes, save_model
from vdnif_addon.model.network import IntersectionNetwork, readout
from vdnif_addon.settings import Heads, NetworkConfig

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"

CONFIG = NetworkConfig(
    levels=2,
    base_resolution=8,
    log2_table_size=10,
    width=16,
    depth=2,
    heads=Heads(albedo=False, material_count=3),
)


def metadata(config=CONFIG, **changes):
    return ModelMetadata.from_dict(metadata_dict(metadata_module, config, **changes), "test.vdnif")


META = metadata()


@pytest.fixture
def network():
    torch.manual_seed(0)
    return IntersectionNetwork(CONFIG)


@pytest.fixture
def saved(tmp_path, network):
    path = tmp_path / "model.vdnif"
    save_model(path, network, META)
    return path


def test_round_trip_gives_identical_outputs_and_metadata(saved, network):
    loaded, meta = load_model(saved)
    assert not loaded.training and meta.network_config == CONFIG
    assert meta == META and meta.version == FORMAT_VERSION
    p0, p1 = torch.rand(2, 50, 3)
    with torch.no_grad():
        expected, actual = network(p0, p1), loaded(p0, p1)
    assert expected.keys() == actual.keys()
    assert all(torch.equal(expected[key], actual[key]) for key in expected)
    assert meta.training.steps == 12 and meta.training.val_poses == (1, 4)
    assert meta.grid.origin == (-1.0, -2.0, 0.5) and meta.grid.resolution == 8
    table = metadata_dict(metadata_module, CONFIG)["albedo_table"]
    np.testing.assert_array_equal(meta.albedo_colors(), np.array(table, np.float32))
    assert meta.albedo_colors().dtype == np.float32 and meta.material_slots == (0, 1, 2)
    assert meta.train_poses == ({"frame": 1.0},)
    assert model_bytes(saved) == os.path.getsize(saved) > 0
    assert os.stat(saved).st_mode & 0o777 == 0o644     # readable by the farm, like any file


def test_point_fields_round_trip(tmp_path):
    """A network whose albedo and normal are fields at the hit (``albedo_mode`` and
    ``normal_mode`` "hit") keeps its modes and the fields' tables and MLPs: the loaded one
    predicts the same albedo and normal."""
    torch.manual_seed(1)
    config = dataclasses.replace(CONFIG, heads=Heads(albedo=True), albedo_mode="hit",
                                 normal_mode="hit")
    network = IntersectionNetwork(config)
    with torch.no_grad():
        network.albedo_field.grid.table.normal_()
        network.normal_field.grid.table.normal_()
    path = tmp_path / "field.vdnif"
    save_model(path, network, metadata(config))
    loaded, meta = load_model(path)
    assert (meta.network_config.albedo_mode, meta.network_config.normal_mode) == ("hit", "hit")
    assert loaded.albedo_field is not None and loaded.normal_field is not None
    p0, p1 = torch.rand(2, 50, 3)
    rest_len = torch.rand(50) * 0.1
    with torch.no_grad():                   # half the segments are candidates
        median = float(torch.sigmoid(network(p0, p1)["occlusion"]).median())
    network.thresholds = loaded.thresholds = Thresholds(median, median)
    expected = network.predict(p0, p1, rest_len, 0.1)
    actual = loaded.predict(p0, p1, rest_len, 0.1)
    assert expected["candidate"].any() and expected["normal"].abs().sum() > 0
    for key in ("albedo", "normal"):
        assert torch.equal(actual[key], expected[key])


def test_write_is_atomic_and_leaves_no_temporary_files(tmp_path, saved, network, monkeypatch):
    assert os.listdir(tmp_path) == ["model.vdnif"]
    good = saved.read_bytes()

    class FullDisk(io.FileIO):
        """A file on a disk that fills after a few bytes."""

        def write(self, data):
            super().write(bytes(data)[:19])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(model_file, "open", lambda name, mode: FullDisk(name, mode),
                        raising=False)
    with pytest.raises(VDNIFError, match="model.vdnif.*no space left on device"):
        save_model(saved, network, META)
    assert saved.read_bytes() == good
    assert os.listdir(tmp_path) == ["model.vdnif"]


def test_save_rejects_a_network_other_than_the_metadata_describes(tmp_path, network):
    with pytest.raises(VDNIFError, match="different config"):
        save_model(tmp_path / "a.vdnif", network, metadata(NetworkConfig()))
    with pytest.raises(VDNIFError, match="a.vdnif"):
        save_model(tmp_path / "missing" / "a.vdnif", network, META)
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
    archive["version"] = FORMAT_VERSION + 1
    torch.save(archive, saved)
    with pytest.raises(
        VDNIFError, match=f"model.vdnif has format version {FORMAT_VERSION + 1}.*update"
    ):
        load_model(saved)


@pytest.mark.parametrize("version", [1, FORMAT_VERSION - 1])
def test_an_older_format_version_is_refused_with_one_line_that_says_to_retrain(saved, version):
    """Files of an older format (the first stored the hash table feature-major, the second
    an untyped metadata dict) are not migrated: one line names the file and says what to
    do."""
    archive = torch.load(saved, weights_only=True)
    archive["version"] = version
    torch.save(archive, saved)
    with pytest.raises(VDNIFError) as refused:
        load_model(saved)
    message = str(refused.value)
    assert message == (f"model file {saved} has format version {version}, older than this "
                       f"add-on reads ({FORMAT_VERSION}): train it again")
    assert "\n" not in message


def _stored(path):
    """The payload exactly as the file holds it: (metadata dict, state dict)."""
    archive = torch.load(path, weights_only=True)
    inner = torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), weights_only=True)
    return inner["metadata"], inner["state_dict"]


def _restore(path, stored_metadata, state_dict):
    """Writes a payload as given (no check), with a matching checksum."""
    buffer = io.BytesIO()
    torch.save({"metadata": stored_metadata, "state_dict": state_dict}, buffer)
    data = buffer.getvalue()
    archive = torch.load(path, weights_only=True)
    archive["payload"] = torch.frombuffer(bytearray(data), dtype=torch.uint8)
    archive["sha256"] = hashlib.sha256(data).hexdigest()
    torch.save(archive, path)


@pytest.mark.parametrize("edit, message", [
    (lambda m: m.pop("grid"), "its metadata has no complete grid"),
    (lambda m: m["grid"].pop("extent"), "its metadata has no complete grid"),
    (lambda m: m["grid"].update(resolution=8.5), "grid resolution 8.5 is not an integer"),
    (lambda m: m["grid"].update(voxel_size=0.0), "grid voxel size or extent is not a positive"),
    (lambda m: m["grid"].update(extent=-1.0), "grid voxel size or extent is not a positive"),
    (lambda m: m["grid"].update(extent=2.0), "grid extent 2.0 is not its voxel size 0.125"),
    (lambda m: m["grid"].update(origin=[0.0, float("nan"), 0.0]),
     r"grid origin \[0.0, nan, 0.0\] is not 3 numbers"),
    (lambda m: m["grid"].update(dims=[8, 8]), r"grid dims \[8, 8\] are not 3 counts"),
    (lambda m: m["grid"].update(resolution=999), "grid resolution 999 is outside the allowed"),
    (lambda m: m.update(albedo_table=[[0.1, 0.2, 0.3]] * 2), "albedo table has 2 rows for 3"),
    (lambda m: m.update(albedo_table=[]), r"albedo_table has shape \(0,\), not nx3"),
    (lambda m: m.update(albedo_table=[[0.1, 0.2]] * 3), r"albedo_table has shape \(3, 2\)"),
    (lambda m: m["albedo_table"][1].__setitem__(0, float("inf")),
     "albedo_table has non-finite values"),
    (lambda m: m.update(material_slots=[0, 1]), r"material slots \[0, 1\] are not 3"),
    (lambda m: m.update(thresholds={"occlusion": 1.5, "candidate": 0.5}),
     r"occlusion threshold 1.5 must lie in \(0, 1\]"),
    (lambda m: m.update(thresholds={"occlusion": 0.5, "candidate": 0.0}),
     r"candidate threshold 0.0 must lie in \(0, 1\]"),
    (lambda m: m.update(thresholds={"occlusion": 0.4, "candidate": 0.6}),
     "candidate threshold 0.6 must be at most the occlusion threshold 0.4"),
    (lambda m: m.pop("thresholds"), "its metadata has no thresholds"),
    (lambda m: m.update(train_poses={"frame": 1.0}), "train_poses is not a list of pose"),
    (lambda m: m.update(train_poses=[1.0]), "train_poses is not a list of pose"),
    (lambda m: m.update(object=None), "object None is not text"),
    (lambda m: m.update(object_size=float("nan")), "object_size has non-finite values"),
    (lambda m: m["training"].update(steps=1.5), "training.steps 1.5 is not an integer"),
    (lambda m: m["training"]["validation"].update(hits=float("nan")),
     "training.validation.hits has non-finite values"),
    (lambda m: m["network_config"].update(distance_mode="log1p"),
     "its network config is invalid: .*log1p"),
    (lambda m: m.update(version=FORMAT_VERSION - 1), "older than this add-on reads"),
    (lambda m: m.clear(), "its metadata has no version"),
], ids=lambda value: value if isinstance(value, str) else "")
def test_damaged_metadata_is_refused_with_one_line_naming_the_file(saved, edit, message):
    stored, state = _stored(saved)
    edit(stored)
    _restore(saved, stored, state)
    with pytest.raises(VDNIFError, match=f"^model file .*model.vdnif.*{message}") as refused:
        load_model(saved)
    assert "\n" not in str(refused.value)


def test_the_golden_files_predict_what_the_torch_encoder_predicts():
    """The golden models (``tests/golden/make_goldens.py``) load and predict, through the
    encoder kernel, what the torch twin of the encoder predicts with their table."""
    for name in ("arm-train.vdnif", "arm-render-model.vdnif"):
        network, meta = load_model(GOLDEN / name)
        assert meta.version == FORMAT_VERSION and meta.object == "Arm"
        reference = oracle.from_product(network.encoder, correctly_rounded=True)
        generator = torch.Generator().manual_seed(0)
        p0 = torch.rand(4000, 3, generator=generator)
        p1 = (p0 + 0.05 * torch.randn(4000, 3, generator=generator)).clamp(0, 1)
        length = (p1 - p0).norm(dim=1)
        predicted = network.predict(p0, p1, length, 0.05)
        with torch.no_grad():
            expected = readout(network.heads(reference(p0, p1)), network.config.distance_mode,
                               0.05, length, network.thresholds)
        assert predicted.keys() == expected.keys() | set(network.point_fields())
        for key in expected:
            torch.testing.assert_close(predicted[key], expected[key], rtol=1e-5, atol=1e-6)
        assert predicted["hit_probability"].std() > 1e-3  # varies from segment to segment
        if network.normal_field is not None:    # the field reads the kernel's grid too
            chosen = predicted["candidate"]
            point = p0 + predicted["fraction"][:, None] * (p1 - p0)
            with torch.no_grad():
                grid = oracle.from_product(network.normal_field.grid)
                normal = torch.nn.functional.normalize(
                    network.normal_field.mlp(grid(point[chosen])), dim=1)
            torch.testing.assert_close(predicted["normal"][chosen], normal, rtol=1e-5,
                                       atol=1e-6)


def test_the_stored_thresholds_decide_the_predicted_hits_and_candidates(tmp_path, network):
    """The thresholds of the metadata come back on the network and ``predict`` applies
    them (the renderer's call): hits above the occlusion threshold, candidates above the
    candidate one."""
    p0, p1 = torch.rand(2, 400, 3)
    rest_len = (p1 - p0).norm(dim=1)
    with torch.no_grad():
        probability = torch.sigmoid(network(p0, p1)["occlusion"])
    # Thresholds among the untrained network's probabilities, so that each one tells
    # segments apart.
    low, middle, high = (float(probability.quantile(q)) for q in (0.2, 0.5, 0.8))
    for occlusion, candidate in ((high, low), (middle, middle), (middle, low)):
        path = tmp_path / "calibrated.vdnif"
        network.thresholds = Thresholds(occlusion, candidate)
        save_model(path, network, metadata(
            thresholds={"occlusion": occlusion, "candidate": candidate}))
        loaded, meta = load_model(path)
        assert loaded.thresholds == meta.thresholds == Thresholds(occlusion, candidate)
        predicted = loaded.predict(p0, p1, rest_len, 0.125)
        assert torch.equal(predicted["hit"], probability > occlusion)
        assert torch.equal(predicted["candidate"], probability > candidate)
        assert 0 < predicted["hit"].sum() <= predicted["candidate"].sum() < len(probability)
