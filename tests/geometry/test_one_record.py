"""One record per contract: the voxel grid has one record (``voxels.GridRecord``) that a
built grid makes and that dataset headers, manifests and model files read with the same
rules; training hands the model file's metadata over as typed values, which the file gives
back unchanged; the thresholds are the metadata's, which the loaded network applies; the
secondary rays' offsets come from one place (``inference.secondary``)."""

import pathlib

import numpy as np
import pytest
import torch
from dataset_headers import header_dict
from model_metadata import GRID, metadata_dict

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry.voxels import GridRecord, build_grid
from vdnif_addon.inference import secondary
from vdnif_addon.model import metadata as metadata_module
from vdnif_addon.model import model_file
from vdnif_addon.model.metadata import ModelMetadata, Thresholds
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import SECONDARY_OFFSET, Heads, NetworkConfig
from vdnif_addon.training import fit
from vdnif_addon.training.header import DatasetHeader, DatasetIdentity

GOLDEN_DATASET = pathlib.Path(__file__).resolve().parents[1] / "golden" / "arm-dataset"
CONFIG = NetworkConfig(levels=2, base_resolution=8, log2_table_size=10, width=16, depth=2,
                       heads=Heads(albedo=False, material_count=3))
# Grid entries broken one way each, and the problem both kinds of file name for it.
BAD_GRIDS = [
    (lambda g: g.pop("extent"), "has no complete grid"),
    (lambda g: g.update(colour=1), "grid has unknown entries 'colour'"),
    (lambda g: g.update(origin=[0.0, 1.0]), "grid origin .* is not 3 numbers"),
    (lambda g: g.update(dims=[8, 0, 8]), "grid dims .* are not 3 counts"),
    (lambda g: g.update(voxel_size=-0.5), "grid voxel size or extent is not a positive"),
    (lambda g: g.update(extent=g["extent"] * 3), "grid extent .* is not its voxel size"),
    (lambda g: g.update(resolution=True), "grid resolution True is not an integer in 4..256"),
    (lambda g: g.update(resolution=2), "grid resolution 2 is outside the allowed range"),
    (lambda g: g.update(occupied_voxels=10**9), "grid occupied_voxels .* is not an integer"),
    (lambda g: g.update(mesh_fingerprint=""), "grid mesh_fingerprint '' is not a string"),
]


def _cube():
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 2) for x in (0, 3)], float)
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return corners, np.array(faces)


def test_a_built_grid_is_recorded_as_its_files_read_it_back():
    grid = build_grid(*_cube(), 6)
    record = grid.record("ab" * 32)
    assert record.dims == tuple(grid.dims.tolist()) and record.extent == grid.extent
    assert record.occupied_voxels == len(grid.cells) and record.resolution == 6
    assert all(type(n) is int for n in record.dims) and type(record.voxel_size) is float

    def fail(problem):
        raise AssertionError(problem)

    assert GridRecord.from_dict(record.to_dict(), fail) == record
    # A model file keeps both optional entries, null where unknown; a header drops them.
    unknown = grid.record()
    assert unknown.to_dict(with_none=True)["mesh_fingerprint"] is None
    assert "mesh_fingerprint" not in unknown.to_dict()
    assert GridRecord.from_dict(unknown.to_dict(with_none=True), fail) == unknown


def test_header_manifest_and_model_file_hold_the_same_record():
    header = DatasetHeader.from_dict(header_dict(), "dataset header 'h.json'")
    identity = DatasetIdentity.from_dict(header.identity().to_dict(), "manifest 'm'")
    model = ModelMetadata.from_dict(metadata_dict(metadata_module, CONFIG), "m.vdnif")
    assert type(header.grid) is type(identity.grid) is type(model.grid) is GridRecord
    assert identity.grid.placement() == header.grid.placement()
    assert model.grid == GridRecord(**GRID)


@pytest.mark.parametrize("edit, problem", BAD_GRIDS)
def test_headers_and_model_files_refuse_a_bad_grid_with_the_same_problem(edit, problem):
    data = header_dict()
    edit(data["grid"])
    with pytest.raises(VDNIFError, match=f"^dataset header 'h.json': {problem}"):
        DatasetHeader.from_dict(data, "dataset header 'h.json'")
    grid = dict(GRID)
    edit(grid)
    with pytest.raises(VDNIFError,
                       match=f"^model file m.vdnif is damaged: its metadata {problem}"):
        ModelMetadata.from_dict(metadata_dict(metadata_module, CONFIG, grid=grid), "m.vdnif")
    fields = dict(GRID)
    edit(fields)
    if set(fields) <= set(GRID):           # a record made in the process is checked too
        with pytest.raises((VDNIFError, TypeError)):
            GridRecord(**fields)


def test_training_makes_the_metadata_its_model_file_gives_back(tmp_path, monkeypatch):
    """``fit_model`` hands the metadata over as typed values (no plain-data round trip):
    they are those the file gives back, to the type (the file would differ otherwise)."""
    made = []
    save = fit.save_model
    monkeypatch.setattr(fit, "save_model",
                        lambda out, network, metadata: (made.append(metadata),
                                                        save(out, network, metadata)))
    out = tmp_path / "m.vdnif"
    fit.fit_model(GOLDEN_DATASET, "proposed", out,
                  dict(steps=4, batch_size=256, log2_table_size=10, normal_log2_table_size=10,
                       device="cpu", seed=0, val_fraction=0.4))
    (metadata,) = made
    _, loaded = model_file.load_model(out)
    assert repr(loaded.to_dict()) == repr(metadata.to_dict())
    assert loaded == metadata and metadata.training.validation is not None
    assert metadata.grid.mesh_fingerprint is None      # the golden header names none


def test_the_model_file_keeps_the_metadatas_thresholds_and_the_network_applies_them(
        tmp_path):
    torch.manual_seed(0)
    network = IntersectionNetwork(CONFIG)
    network.thresholds = Thresholds(0.9, 0.8)          # not saved: the metadata's are
    metadata = ModelMetadata.from_dict(
        metadata_dict(metadata_module, CONFIG, thresholds={"occlusion": 0.3, "candidate": 0.1}),
        "m.vdnif")
    model_file.save_model(tmp_path / "m.vdnif", network, metadata)
    loaded, meta = model_file.load_model(tmp_path / "m.vdnif")
    assert loaded.thresholds is meta.thresholds
    assert meta.thresholds == Thresholds(0.3, 0.1)
    p0, p1 = torch.rand(2, 300, 3)
    with torch.no_grad():
        probability = torch.sigmoid(loaded(p0, p1)["occlusion"])
    predicted = loaded.predict(p0, p1, (p1 - p0).norm(dim=1), 0.125)
    assert torch.equal(predicted["hit"], probability > 0.3)
    assert torch.equal(predicted["candidate"], probability > 0.1)


def test_the_secondary_offsets_come_from_one_place():
    size, voxel = 2.5, 0.01
    assert secondary.exact_offset(size) == SECONDARY_OFFSET * size
    model = ModelMetadata.from_dict(metadata_dict(metadata_module, CONFIG), "m.vdnif")
    assert secondary.model_offset(model, size, voxel) == secondary.network_offset(size, voxel)
    trained = ModelMetadata.from_dict(metadata_dict(metadata_module, CONFIG, training=dict(
        model.training.to_dict(), validation={"distance_mae_voxels": 4.0})), "m.vdnif")
    offset = secondary.model_offset(trained, size, voxel)
    assert offset == secondary.network_offset(size, voxel, 4.0) > secondary.exact_offset(size)
    described = secondary.SecondarySettings().describe(offset, size)
    assert described["network_offset"] == offset / size
    assert described["offset"] == SECONDARY_OFFSET
    assert "network_offset" not in secondary.SecondarySettings().describe()
