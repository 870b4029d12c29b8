"""Seven seeded mutation campaigns over whole files a user hands over: the golden arm model
(``tests/golden/arm-train.vdnif``) and the golden arm shard (``tests/golden/arm-dataset``),
their bytes flipped, their zip headers' fields set to other values, cut short or extended,
the model's inner payload changed behind a valid checksum, and the shard's rows given
absurd values written back by VDNIF's own writer.

Every outcome must be a one-line VDNIFError, or a load whose result is sound: a model
whose network answers finitely, a shard whose rows agree with their points (checked here
against the rows themselves). No other exception, no hang (``CASE_LIMIT_S`` a case). Each
campaign runs at most ``CASES`` cases and stops early after ``CAMPAIGN_S`` seconds, so it
takes a few seconds on a loaded machine; case ``i`` of a seed is the same mutation however
many ran before it, so a failure's seed and case replay it.
"""

import hashlib
import io
import json
import random
import shutil
import time

import numpy as np
import pytest
import torch
from conftest import REPO
from test_fuzz_contracts import case_limit, check_refusal

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model.model_file import load_model
from vdnif_addon.training import dataset
from vdnif_addon.training.header import DatasetHeader

GOLDEN = REPO / "tests" / "golden"
MODEL = GOLDEN / "arm-train.vdnif"
SHARD = next((GOLDEN / "arm-dataset").glob("*.npz"))
CASES = 60
CAMPAIGN_S = 4.0            # a campaign stops after this; each case is also bounded
CASE_LIMIT_S = 10
SEED = 7
VALUES = (0.0, -0.0, -1.0, 1.0, 2.0, 0.5, 1e-45, 65504.0, 3e38, -3e38, float("nan"),
          float("inf"), -float("inf"), 1e9)


# --------------------------------------------------------------------------- mutations


def zip_records(data):
    """[(offset, size)] of the zip records of ``data``: local file headers, central
    directory entries, the end-of-directory records."""
    records = []
    for signature, size in ((b"PK\x03\x04", 30), (b"PK\x01\x02", 46), (b"PK\x05\x06", 22),
                            (b"PK\x06\x06", 56), (b"PK\x06\x07", 20)):
        start = data.find(signature)
        while start != -1:
            records.append((start, size))
            start = data.find(signature, start + 1)
    return records


def flip_bytes(rng, data):
    data = bytearray(data)
    for _ in range(rng.choice((1, 1, 2, 4, 16))):
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8) if rng.random() < 0.5 else (
            rng.randrange(1, 256))
    return bytes(data)


def zip_field(rng, data):
    """One field (1, 2, 4 or 8 bytes at a random place after the signature) of a random
    zip record set to 0, all ones, one more, or a random value."""
    data = bytearray(data)
    offset, size = rng.choice(zip_records(bytes(data)))
    width = rng.choice((1, 2, 4, 8))
    where = offset + 4 + rng.randrange(max(1, size - 4 - width))
    old = int.from_bytes(data[where:where + width], "little")
    new = rng.choice((0, (1 << 8 * width) - 1, old + 1, rng.getrandbits(8 * width)))
    data[where:where + width] = (new % (1 << 8 * width)).to_bytes(width, "little")
    return bytes(data)


def cut_or_extend(rng, data):
    kind = rng.randrange(3)
    if kind == 0:
        return data[:rng.randrange(len(data))]
    if kind == 1:
        return data + rng.randbytes(rng.choice((1, 100, 10_000)))
    start = rng.randrange(len(data))
    piece = data[start:start + rng.choice((4, 64, 4096))]
    where = rng.randrange(len(data))
    return data[:where] + piece + data[where:]


def payload_bytes(rng, data):
    """The model's inner payload mutated (bytes flipped, a zip field set, or cut) and its
    checksum made to match, so the mutation reaches the payload's reader."""
    archive = torch.load(io.BytesIO(data), weights_only=True)
    payload = archive["payload"].numpy().tobytes()
    payload = rng.choice((flip_bytes, zip_field, flip_bytes, cut_or_extend))(rng, payload)
    archive["payload"] = torch.frombuffer(bytearray(payload), dtype=torch.uint8)
    archive["sha256"] = hashlib.sha256(payload).hexdigest()
    buffer = io.BytesIO()
    torch.save(archive, buffer)
    return buffer.getvalue()


# --------------------------------------------------------------------------- outcomes


def sound_model(path):
    """A loaded model's network answers finitely for segments across its grid."""
    network, metadata = load_model(path)
    points = torch.rand(64, 3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        outputs = network(points, points.flip(0))
    assert all(torch.isfinite(value).all() for value in outputs.values()), path
    return "loaded"


def sound_shard(folder):
    """A read shard's rows agree with themselves: the rest length is the distance of its
    points in rest units, hits' normals have unit length, points lie in the grid."""
    data, shards = dataset.read_dataset(folder)
    extent = data.header.grid.extent
    for shard in shards:
        rows = {name: np.asarray(shard[name], np.float64) for name in dataset.ARRAYS}
        distance = np.linalg.norm(rows["p1"] - rows["p0"], axis=1) * extent
        assert np.all(np.abs(rows["rest_len"] - distance) <= 2e-3 * distance + 1e-4 * extent)
        hit = rows["hit"] != 0
        assert np.all(np.abs(np.linalg.norm(rows["normal"][hit], axis=1) - 1) < 0.02)
        assert rows["p0"].min() >= -0.02 and rows["p0"].max() <= 1.02
        assert np.isfinite(rows["seg_len"]).all() and rows["seg_len"].min() >= 0
    return "loaded"


def run_campaign(name, mutate, target, check, tmp_path):
    """Up to CASES cases of ``mutate(rng, bytes)`` on ``target``'s bytes, each written to
    a fresh file and given to ``check``; returns {outcome: count}."""
    original = target.read_bytes()
    outcomes = {"refused": 0, "loaded": 0}
    start = time.monotonic()
    for index in range(CASES):
        if index and time.monotonic() - start > CAMPAIGN_S:
            break
        rng = random.Random(f"{name}-{SEED}-{index}")
        place = tmp_path / f"{name}-{index}"
        place.mkdir()
        try:
            with case_limit(CASE_LIMIT_S):
                mutated = mutate(rng, original)
                outcomes[check(place, mutated)] += 1
        except VDNIFError as exc:
            check_refusal(exc, str(place))
            outcomes["refused"] += 1
        except Exception as exc:
            pytest.fail(f"campaign {name} seed {SEED} case {index}: {type(exc).__name__}: "
                        f"{str(exc)[:500]}")
        shutil.rmtree(place)
    print(name, outcomes)
    return outcomes


def model_case(place, data):
    path = place / "m.vdnif"
    path.write_bytes(data)
    return sound_model(path)


def shard_case(place, data):
    folder = place / "data"
    shutil.copytree(SHARD.parent, folder)
    (folder / SHARD.name).write_bytes(data)
    return sound_shard(folder)


@pytest.mark.parametrize("name, mutate", [
    ("model-bytes", flip_bytes), ("model-zip-fields", zip_field),
    ("model-cut-or-extended", cut_or_extend), ("model-payload", payload_bytes)])
def test_a_mutated_model_file_is_refused_on_one_line_or_loads_sound(name, mutate, tmp_path):
    outcomes = run_campaign(name, mutate, MODEL, model_case, tmp_path)
    assert sum(outcomes.values()) >= 5 and outcomes["refused"], outcomes


@pytest.mark.parametrize("name, mutate", [
    ("shard-bytes", flip_bytes), ("shard-zip-fields-cut-or-extended",
                                  lambda rng, data: rng.choice((zip_field, cut_or_extend))(
                                      rng, data))])
def test_a_mutated_shard_file_is_refused_on_one_line_or_reads_sound(name, mutate, tmp_path):
    outcomes = run_campaign(name, mutate, SHARD, shard_case, tmp_path)
    assert sum(outcomes.values()) >= 5 and outcomes["refused"], outcomes


def test_shard_rows_of_absurd_values_are_refused_on_one_line_or_read_sound(tmp_path):
    """Rows of a random array set to values such as NaN, 3e38, 0, -1 or 65504 and the shard
    written again by VDNIF's writer (its header kept): what the reader takes must agree
    with itself (``sound_shard``)."""
    _, [shard] = dataset.read_dataset(SHARD.parent)
    rows = {name: np.array(shard[name]) for name in dataset.ARRAYS}
    header = DatasetHeader.from_dict(json.loads(SHARD.with_suffix(".json").read_text()), "h")

    def mutate(rng, _):
        arrays = {name: array.copy() for name, array in rows.items()}
        for _ in range(rng.choice((1, 2, 3))):
            name = rng.choice(("p0", "p1", "seg_len", "rest_len", "t0", "hit_frac", "normal",
                               "albedo", "hit"))
            chosen = rng.sample(range(len(arrays[name])), rng.choice((1, 5, 100)))
            value = rng.choice(VALUES) if name != "hit" else rng.choice((0, 1, 2, 255))
            with np.errstate(all="ignore"):
                arrays[name][chosen] = np.asarray(value).astype(arrays[name].dtype)
        return arrays

    def check(place, arrays):
        folder = place / "data"
        with np.errstate(over="ignore"):        # the writer stores normals in float16
            dataset.write_shard(folder, SHARD.stem, arrays, header)
        return sound_shard(folder)

    outcomes = run_campaign("shard-values", mutate, SHARD, check, tmp_path)
    assert sum(outcomes.values()) >= 5 and outcomes["refused"], outcomes


def test_the_campaigns_touch_every_zip_record_kind():
    """The zip-field campaigns reach the local headers, the directory and its end."""
    for path in (MODEL, SHARD):
        data = path.read_bytes()
        kinds = {data[offset:offset + 4] for offset, _ in zip_records(data)}
        assert {b"PK\x03\x04", b"PK\x01\x02", b"PK\x05\x06"} <= kinds, path
