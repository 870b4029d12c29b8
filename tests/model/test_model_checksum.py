"""A model file whose payload was changed after it was written (a weight edited, the archive
otherwise whole and loadable) is refused by its checksum, not loaded (no bpy)."""

import hashlib
import io
import pathlib

import pytest
import torch

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model.model_file import load_model

GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden" / "arm-render-model.vdnif"


def edited(path, out, checksum):
    """The model file ``path`` with one weight changed, written to ``out`` as a whole, valid
    archive; ``checksum``: "stale" keeps the file's old SHA-256, "fresh" writes the new."""
    archive = torch.load(path, map_location="cpu", weights_only=True)
    inner = torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), map_location="cpu",
                       weights_only=True)
    name = next(key for key, value in inner["state_dict"].items()
                if value.is_floating_point() and value.numel() > 1)
    inner["state_dict"][name] = inner["state_dict"][name] + 0.5
    buffer = io.BytesIO()
    torch.save(inner, buffer)
    payload = buffer.getvalue()
    if checksum == "fresh":
        archive["sha256"] = hashlib.sha256(payload).hexdigest()
    archive["payload"] = torch.frombuffer(bytearray(payload), dtype=torch.uint8)
    torch.save(archive, out)
    return name


def test_an_edited_payload_under_the_old_checksum_is_refused(tmp_path):
    out = tmp_path / "edited.vdnif"
    edited(GOLDEN, out, "stale")
    with pytest.raises(VDNIFError, match="checksum does not match"):
        load_model(out)


def test_the_same_edit_under_its_own_checksum_loads_with_the_edit(tmp_path):
    """The edited archive is otherwise sound: only the checksum tells it apart above."""
    out = tmp_path / "resigned.vdnif"
    name = edited(GOLDEN, out, "fresh")
    network, _ = load_model(out)
    original, _ = load_model(GOLDEN)
    difference = network.state_dict()[name] - original.state_dict()[name]
    torch.testing.assert_close(difference, torch.full_like(difference, 0.5))
