"""How the voxel corners followed the mesh, recorded in the dataset header and the model
file: files written before the record read as the armature copy and keep working."""

import json
import pathlib

import pytest
import torch
from model_metadata import metadata_dict

from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry.capture import ARMATURE_COPY, SURFACE_BOUND
from vdnif_addon.model import metadata as metadata_module
from vdnif_addon.model.metadata import ModelMetadata
from vdnif_addon.model.model_file import load_model, save_model
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import Heads, NetworkConfig
from vdnif_addon.training.header import DatasetHeader

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"
CONFIG = NetworkConfig(levels=2, base_resolution=8, log2_table_size=10, width=16, depth=2,
                       heads=Heads(albedo=False, material_count=1))


@pytest.mark.parametrize("name", ["arm-train.vdnif", "arm-render-model.vdnif"])
def test_golden_models_read_as_the_armature_copy(name):
    network, metadata = load_model(GOLDEN / name)
    assert metadata.corners_follow == ARMATURE_COPY
    assert "corners_follow" not in metadata.to_dict()          # files stay as they were


@pytest.mark.parametrize("follow", SURFACE_BOUND)
def test_a_surface_model_keeps_its_record_through_the_file(tmp_path, follow):
    metadata = ModelMetadata.from_dict(
        metadata_dict(metadata_module, CONFIG, corners_follow=follow), "m.vdnif")
    torch.manual_seed(0)
    save_model(tmp_path / "m.vdnif", IntersectionNetwork(CONFIG), metadata)
    assert load_model(tmp_path / "m.vdnif")[1].corners_follow == follow


def test_an_unknown_record_is_one_line_naming_the_file():
    data = metadata_dict(metadata_module, CONFIG, corners_follow="magic")
    with pytest.raises(VDNIFError) as caught:
        ModelMetadata.from_dict(data, "m.vdnif")
    message = str(caught.value)
    assert "\n" not in message and "model file m.vdnif" in message and "'magic'" in message


def test_dataset_headers_write_the_record_only_for_the_surface():
    """The golden shard (written before the record) reads as the armature copy and writes
    back unchanged; a surface shard keeps its record; an unknown one is refused."""
    data = json.loads((GOLDEN / "arm-dataset" / "shard-000000-000003.json").read_text())
    header = DatasetHeader.from_dict(data, "golden")
    assert header.corners_follow == ARMATURE_COPY and header.to_dict() == data
    for follow in SURFACE_BOUND:
        surface = DatasetHeader.from_dict(dict(data, corners_follow=follow), "shard")
        assert surface.corners_follow == follow
        assert surface.to_dict()["corners_follow"] == follow
    with pytest.raises(VDNIFError, match="corners follow 'magic'"):
        DatasetHeader.from_dict(dict(data, corners_follow="magic"), "shard")
