"""How a shard stores its rows (``training.packing``): the targets only a hit has for its hit
rows alone, albedo and material only for the heads that need them, float16 where its
rounding is far below what the metrics resolve; read back as the rows in memory, and a
version 1 shard (every array dense, float32) read as it is."""

import json
import re

import numpy as np
import pytest
from dataset_headers import header_dict

from vdnif_addon import limits
from vdnif_addon.errors import VDNIFError
from vdnif_addon.training import dataset, packing
from vdnif_addon.training.header import DatasetHeader

NAME = "shard-000000-000002"


def rows(n=200, seed=3, materials=3):
    """The rows of a two-pose shard as the walk makes them: targets zero on misses."""
    rng = np.random.default_rng(seed)
    hit = rng.random(n) < 0.3
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    records = {
        "p0": rng.random((n, 3)), "p1": rng.random((n, 3)), "seg_len": rng.random(n),
        "rest_len": np.zeros(n), "t0": rng.random(n) * 5, "hit": hit,
        "hit_frac": np.where(hit, rng.random(n), 0), "normal": normal * hit[:, None],
        "albedo": rng.random((n, 3)) * hit[:, None],
        "material": np.where(hit, rng.integers(0, materials, n), 0),
        "pose": np.sort(rng.integers(0, 2, n)), "ray": rng.integers(0, 16, n)}
    records = {name: np.asarray(records[name]).astype(dtype)
               for name, (dtype, _) in dataset.ARRAYS.items()}
    # the rest length of the stored points, in rest units (the header's grid extent)
    extent = header_dict()["grid"]["extent"]
    records["rest_len"] = (np.linalg.norm(records["p1"].astype(np.float64) - records["p0"],
                                          axis=1) * extent).astype(np.float32)
    return records


def write(folder, records, **heads):
    header = header_dict(pose_range=(0, 2), segments=len(records["pose"]), **heads)
    header["counts"]["hits"] = int(records["hit"].sum())
    dataset.write_shard(folder, NAME, records, DatasetHeader.from_dict(header, "test"))
    return folder / f"{NAME}.npz"


@pytest.mark.parametrize("albedo, materials", [(True, 3), (False, 3), (False, 1)])
def test_rows_read_back_as_written_within_float16_where_stored_so(tmp_path, albedo,
                                                                   materials):
    records = rows(materials=materials)
    path = write(tmp_path, records, albedo=albedo, materials=materials)
    hit = records["hit"] != 0
    with np.load(path) as stored:
        kept = set(stored.files)
        assert ("albedo" in kept) == albedo and ("material" in kept) == (materials > 1)
        for name in kept:
            rows_stored = hit.sum() if name in packing.HIT_ROWS else len(hit)
            assert len(stored[name]) == rows_stored, name
        assert stored["normal"].dtype == np.float16 and stored["pose"].dtype == np.int16
        assert stored["p0"].dtype == np.float32 and stored["t0"].dtype == np.float32
    # without an albedo head a hit's albedo is its material's row of the table, and with
    # one material its material is 0: what the reader gives back for arrays not stored
    table = np.asarray(header_dict(materials=materials)["albedo_table"], np.float32)
    if not albedo:
        records["albedo"] = np.where(hit[:, None], table[records["material"]], 0)
    if materials == 1:
        records["material"][:] = 0
    _, [shard] = dataset.read_dataset(tmp_path)
    assert set(shard) == set(dataset.ARRAYS)
    for name, (dtype, _) in dataset.ARRAYS.items():
        expected = records[name]
        if name in kept and packing.STORED_TYPES.get(name) == np.float16:
            expected = expected.astype(np.float16).astype(dtype)
        assert shard[name].dtype == dtype, name
        np.testing.assert_array_equal(shard[name], expected, err_msg=name)
    # the float16 rounding, against what the metrics resolve (0.03 voxels, 2 degrees)
    assert np.abs(shard["hit_frac"] - records["hit_frac"]).max() <= 2.0 ** -12
    cosine = np.sum(shard["normal"][hit] * records["normal"][hit], 1) / np.linalg.norm(
        shard["normal"][hit], axis=1)
    assert np.degrees(np.arccos(np.clip(cosine, -1, 1))).max() < 0.05


def test_a_version_1_shard_reads_as_it_is(tmp_path):
    """Every array dense and float32 as the first format wrote them: read unchanged."""
    records = rows()
    header = header_dict(pose_range=(0, 2), segments=len(records["pose"]), materials=3)
    header["version"] = 1
    (tmp_path / f"{NAME}.json").write_text(json.dumps(header))
    np.savez(tmp_path / f"{NAME}.npz", **records)
    merged, [shard] = dataset.read_dataset(tmp_path)
    assert merged.header.version == 1 and set(shard) == set(dataset.ARRAYS)
    for name, array in records.items():
        np.testing.assert_array_equal(shard[name], array, err_msg=name)


def test_a_hit_array_of_other_rows_than_the_hits_is_one_line(tmp_path):
    path = write(tmp_path, rows(materials=3), materials=3)
    with np.load(path) as stored:
        arrays = {name: stored[name] for name in stored.files}
    arrays["normal"] = arrays["normal"][:-1]
    np.savez(path, **arrays)
    with pytest.raises(VDNIFError, match=r"^dataset shard '.*' array 'normal' has \d+ rows, "
                                         r"its 'hit' array \d+ hits$"):
        dataset.read_dataset(tmp_path)


def test_every_pose_index_fits_the_stored_type():
    assert limits.MAX_POSES <= np.iinfo(packing.STORED_TYPES["pose"]).max


def test_a_deferred_row_check_refuses_a_shard_at_its_first_read(tmp_path):
    """``read_dataset(defer_row_check=True)`` (the header a training names its model by, and
    the training's own read) reads no row: a shard whose points lie far outside the grid
    gives its header and the headers' segment count, and is refused on one line when any of
    its arrays is first read, as the full read refuses it; the training that reads it
    leaves no model folder behind."""
    records = rows(materials=3)
    records["p0"][5] = 3e38
    write(tmp_path / "data", records, materials=3)
    merged, [shard] = dataset.read_dataset(tmp_path / "data", defer_row_check=True)
    assert merged.segments == len(records["pose"])
    pattern = r"^dataset shard '.*' array 'p0' has points outside the grid"
    with pytest.raises(VDNIFError, match=pattern):
        shard["ray"]
    with pytest.raises(VDNIFError, match=pattern):
        dataset.read_dataset(tmp_path / "data")
    from vdnif_addon.training.fit import fit_model
    with pytest.raises(VDNIFError, match=pattern):
        fit_model(tmp_path / "data", "proposed", tmp_path / "models" / "m.vdnif", {"steps": 2})
    assert not (tmp_path / "models").exists()


@pytest.mark.parametrize("defects, first", [
    ({"p1": "outside", "hit_frac": "outside"}, r"array 'p1' has points outside the grid"),
    ({"hit_frac": "outside", "p0": "outside"}, r"array 'p0' has points outside the grid"),
    ({"seg_len": "non-finite", "pose": "outside"}, r"array 'seg_len' has non-finite values"),
    ({"pose": "outside", "hit_frac": "non-finite"}, r"array 'hit_frac' has non-finite"),
])
def test_a_shard_with_several_defects_is_refused_for_the_first_in_array_order(
        tmp_path, defects, first):
    """Arrays read and checked two at a time report the first defect in ``ARRAYS``' order,
    as arrays read one at a time would, by either read; whichever defect a thread meets
    first."""
    records = rows(materials=3)
    for name, defect in defects.items():
        if defect == "non-finite":
            records[name][7] = np.nan
        elif name == "pose":
            records[name][7] = 10_000
        else:
            records[name][7] = 3e38 if name in ("p0", "p1") else 2.0
    write(tmp_path / "data", records, materials=3)
    order = list(dataset.ARRAYS)
    assert order.index(re.search(r"array '(\w+)'", first)[1]) == min(map(order.index, defects))
    with pytest.raises(VDNIFError, match=f"^dataset shard '.*' {first}"):
        dataset.read_dataset(tmp_path / "data")
    _, [shard] = dataset.read_dataset(tmp_path / "data", defer_row_check=True)
    with pytest.raises(VDNIFError, match=f"^dataset shard '.*' {first}"):
        shard["p0"]


def test_a_deferred_check_hands_each_array_over_once_and_reads_it_again_after(tmp_path):
    """The sound shard's arrays, checked at the first read, are the full read's; the one
    given is let go (the reader holds the only copy), and a second read of it reads the file
    again, to the same values."""
    records = rows(materials=3)
    write(tmp_path, records, materials=3)
    _, [checked] = dataset.read_dataset(tmp_path)
    _, [deferred] = dataset.read_dataset(tmp_path, defer_row_check=True)
    first = {name: deferred[name] for name in dataset.ARRAYS}
    assert not deferred._unread
    for name in dataset.ARRAYS:
        np.testing.assert_array_equal(first[name], checked[name], err_msg=name)
        again = deferred[name]
        assert again is not first[name]
        np.testing.assert_array_equal(again, checked[name], err_msg=name)
