"""The dataset header as a typed contract (``training.header``) and the shard reader around
it (``training.dataset.read_dataset``): every bad header, manifest or shard file is one
VDNIFError line naming the file, before anything blocks, recurses or allocates."""

import io
import json
import os
import pathlib
import re
import threading
import zipfile

import numpy as np
import pytest
from conftest import REPO
from dataset_headers import header_dict
from source_scan import matching_lines

from vdnif_addon import limits
from vdnif_addon.errors import VDNIFError
from vdnif_addon.geometry.voxels import GRID_KEYS
from vdnif_addon.safe_io import MAX_DEPTH
from vdnif_addon.training import dataset
from vdnif_addon.training.header import VERSION, DatasetHeader

GOLDEN_SHARD = REPO / "tests" / "golden" / "arm-dataset" / "shard-000000-000003.json"


def _records(n=4, pose=0):
    records = {name: np.zeros((n, *shape), dtype)
               for name, (dtype, shape) in dataset.ARRAYS.items()}
    records["pose"][:] = pose
    return records


def _write(folder, pose_range=(0, 1), n=4, **changes):
    """One valid shard of ``n`` rows for ``pose_range`` in ``folder``; returns its stem."""
    name = f"shard-{pose_range[0]:06d}-{pose_range[1]:06d}"
    header = dict(header_dict(pose_range=pose_range, segments=n), **changes)
    dataset.write_shard(folder, name, _records(n, pose_range[0]),
                        DatasetHeader.from_dict(header, "test header"))
    return pathlib.Path(folder) / name


def _one_line_error(call, pattern):
    with pytest.raises(VDNIFError) as caught:
        call()
    message = str(caught.value)
    assert "\n" not in message and re.search(pattern, message), message
    return message


# --------------------------------------------------------------------------- the contract


def test_the_golden_header_reads_and_writes_back_unchanged():
    data = json.loads(GOLDEN_SHARD.read_text())
    header = DatasetHeader.from_dict(data, "golden")
    assert header.to_dict() == data
    assert list(header.to_dict()) == list(data)              # the same key order on disk
    assert header.voxel_size == header.grid.voxel_size == 0.25
    assert header.grid.dims == (4, 4, 14) and header.pose_range == (0, 3)
    assert header.counts.segments == header.segments == 4543
    assert header.heads.network_heads().sizes() == {"occlusion": 1, "distance": 1, "normal": 3}
    assert header.grazing_fraction is None                    # made before grazing rays


def _set(path, value):
    """An edit that sets the entry at the key path ``path`` of a header dict."""
    def edit(data):
        *parents, last = path
        for key in parents:
            data = data[key]
        data[last] = value
    return edit


def _drop(key):
    return lambda data: data.pop(key)


BAD_HEADERS = [
    ("no grid", _drop("grid"), r"has no complete grid"),
    ("grid a list", _set(["grid"], [1, 2, 3]), r"has no complete grid"),
    ("grid without dims", lambda d: d["grid"].pop("dims"), r"has no complete grid"),
    ("grid origin NaN", _set(["grid", "origin", 0], float("nan")), r"grid origin .* 3 numbers"),
    ("grid dims floats", _set(["grid", "dims"], [8.0, 8, 8]), r"grid dims .* 3 counts"),
    ("grid resolution huge", _set(["grid", "resolution"], 10**6), r"grid resolution"),
    ("lying voxel size", _set(["voxel_size"], 0.5), r"voxel size .* differs from the grid's"),
    ("no object", _set(["object"], ""), r"names no object"),
    ("object size inf", _set(["object_size"], float("inf")), r"object size inf"),
    ("pose range a string", _set(["pose_range"], "0:1"), r"pose range '0:1' is not two"),
    ("pose range of strings", _set(["pose_range"], ["0", "1"]), r"pose range"),
    ("pose range floats", _set(["pose_range"], [0.0, 1.0]), r"pose range"),
    ("pose range three", _set(["pose_range"], [0, 1, 2]), r"pose range"),
    ("pose range longer than the poses", _set(["pose_range"], [0, 2]),
     r"span its 1 poses"),
    ("pose range reversed", _set(["pose_range"], [1, 0]), r"pose range"),
    ("poses not objects", _set(["poses"], [1.0]), r"poses are not a list"),
    ("pose NaN", _set(["poses", 0, "frame"], float("nan")),
     r"pose figure 'poses\[0\].frame' is not a finite number"),
    ("seed negative", _set(["seed"], -1), r"seed -1 is not an integer"),
    ("seed a bool", _set(["seed"], True), r"seed True is not an integer"),
    ("counts negative", _set(["counts", "hits"], -1), r"counts hits -1"),
    ("counts a list", _set(["counts"], [1, 2, 3]), r"counts is not a JSON object"),
    ("segments negative", _set(["segments"], -4), r"segments -4"),
    ("segments beyond the limit", _set(["segments"], limits.MAX_SHARD_SEGMENTS + 1),
     r"segments \d+ is not an integer"),
    ("albedo table empty", _set(["albedo_table"], []), r"albedo table has 0 rows"),
    ("albedo table of strings", _set(["albedo_table"], [["NaN"] * 3]),
     r"the albedo table is not all finite"),
    ("albedo row short", _set(["albedo_table"], [[0.5, 0.5]]),
     r"the albedo table is not all finite"),
    ("fewer albedo rows than materials",
     lambda d: d["heads"].update(material=True, material_count=3),
     r"albedo table has 1 rows for 3 materials"),
    ("heads without material_count", lambda d: d["heads"].pop("material_count"),
     r"heads lacks material_count"),
    ("heads material disagrees", _set(["heads", "material"], True), r"heads albedo"),
    ("heads zero materials", _set(["heads", "material_count"], 0), r"material_count 0"),
    ("heads slots too few", _set(["heads", "material_slots"], []), r"material_slots"),
    ("inverted cells per pose", _set(["inverted_cells"], [0, 0]), r"inverted_cells"),
    ("timing negative", _set(["timings", "total_s"], -1.0), r"timing total_s"),
    ("versions numbers", _set(["versions", "vdnif"], 1), r"versions are not all strings"),
    ("surface fraction beyond 1", _set(["surface_fraction"], 1.5), r"surface fraction 1.5"),
    ("unknown entry", _set(["colour"], "red"), r"unknown entries 'colour'"),
    ("mode empty", _set(["mode"], ""), r"mode '' is not a name"),
    ("not a header", _set(["format"], "other"), r"is not a VDNIF dataset header"),
    ("version a bool", _set(["version"], True), r"has format version True"),
]


@pytest.mark.parametrize("edit, pattern", [case[1:] for case in BAD_HEADERS],
                         ids=[case[0] for case in BAD_HEADERS])
def test_a_bad_header_is_one_line_naming_it(edit, pattern):
    data = header_dict(segments=4)
    DatasetHeader.from_dict(data, "dataset header 'h.json'")           # valid as made
    edit(data)
    message = _one_line_error(lambda: DatasetHeader.from_dict(data, "dataset header 'h.json'"),
                              pattern)
    assert message.startswith("dataset header 'h.json'")


def test_an_unknown_dataset_version_is_refused_saying_to_generate_it_again(tmp_path):
    shard = _write(tmp_path)
    path = shard.with_suffix(".json")
    for version in (0, VERSION + 1):
        path.write_text(json.dumps(dict(json.loads(path.read_text()), version=version)))
        _one_line_error(lambda: dataset.read_dataset(tmp_path),
                        rf"'{re.escape(str(path))}' has format version {version}, this VDNIF "
                        rf"reads versions 1 to {VERSION}: generate the dataset again")


def test_a_deeply_nested_header_is_one_line_not_a_recursion_error(tmp_path):
    shard = _write(tmp_path)
    path = shard.with_suffix(".json")
    path.write_text("[" * 100_000 + "]" * 100_000)                    # past json's recursion
    _one_line_error(lambda: dataset.read_dataset(tmp_path), r"nests too deeply to be read")
    data = header_dict(segments=4)
    nested = []
    for _ in range(MAX_DEPTH + 5):                                      # within json's limit
        nested = [nested]
    data["poses"] = [{"frame": 1.0, "bones": {"b": nested}}]
    path.write_text(json.dumps(data))
    _one_line_error(lambda: dataset.read_dataset(tmp_path),
                    rf"nests more than {MAX_DEPTH} levels")


# --------------------------------------------------------------------------- the files


def test_a_fifo_named_like_a_shard_is_refused_instead_of_blocking(tmp_path):
    for suffix in (".npz", ".json"):
        folder = tmp_path / suffix[1:]
        folder.mkdir()
        shard = _write(folder).with_suffix(suffix)
        shard.unlink()
        os.mkfifo(shard)
        outcome = []

        def read(folder=folder, outcome=outcome):
            try:
                dataset.read_dataset(folder)
            except VDNIFError as exc:
                outcome.append(str(exc))

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        reader.join(timeout=20)
        if reader.is_alive():                       # blocked in open(): release it, then fail
            with open(shard, "wb"):
                pass
            reader.join(timeout=20)
            pytest.fail(f"reading a dataset with a FIFO '{shard.name}' blocked")
        assert len(outcome) == 1 and "\n" not in outcome[0], outcome
        assert f"'{shard}' is not a regular file" in outcome[0]


def test_overlapping_pose_ranges_are_refused_naming_both_shards(tmp_path):
    first = _write(tmp_path, (0, 1))
    second = _write(tmp_path, (0, 2))
    message = _one_line_error(lambda: dataset.read_dataset(tmp_path), r"overlap")
    assert first.name in message and second.name in message
    assert "poses 0:1" in message and "poses 0:2" in message
    second.with_suffix(".json").unlink()
    second.with_suffix(".npz").unlink()
    _write(tmp_path, (1, 3))                                             # adjacent: fine
    merged, shards = dataset.read_dataset(tmp_path)
    assert len(shards) == 2 and len(merged.poses) == 3 and merged.segments == 8


def test_rows_of_poses_outside_the_shards_pose_range_are_refused(tmp_path):
    shard = _write(tmp_path, (2, 3))
    with np.load(shard.with_suffix(".npz")) as archive:
        arrays = {name: archive[name] for name in archive.files}
    arrays["pose"][1] = 0                                   # a row of a pose of another shard
    np.savez(shard.with_suffix(".npz"), **arrays)
    _one_line_error(lambda: dataset.read_dataset(tmp_path),
                    r"array 'pose' has poses 0..2 outside its pose range 2:3")


def test_the_manifest_is_checked_against_the_shards(tmp_path):
    _write(tmp_path)
    manifest = tmp_path / dataset.MANIFEST
    good = json.loads(manifest.read_text())
    grid = {key: header_dict()["grid"][key] for key in GRID_KEYS}
    assert good == {"object": "Ball", "seed": 0, "grid": grid}
    assert dataset.read_dataset(tmp_path)[0].header.object == "Ball"
    for change, pattern in (({"seed": 3}, r"another seed than the manifest"),
                            ({"object": "Cube"}, r"another object than the manifest"),
                            ({"grid": dict(good["grid"], dims=[4, 8, 8], extent=1.0)},
                             r"another grid than the manifest")):
        manifest.write_text(json.dumps(dict(good, **change)))
        _one_line_error(lambda: dataset.read_dataset(tmp_path), pattern)


@pytest.mark.parametrize("manifest, pattern", [
    ({"grid": [8, 8, 8]}, r"has no complete grid"),
    ({"grid": "8x8x8"}, r"has no complete grid"),
    ({"grid": {"dims": [8, 8, 8]}}, r"has no complete grid"),
    ({"seed": "0"}, r"seed '0' is not an integer"),
    ({"object": 7}, r"names no object"),
    ({"pose_range": "0:1"}, r"manifest has unknown entries 'pose_range'"),
], ids=["grid-list", "grid-string", "grid-incomplete", "seed-string", "object-number",
        "pose-range"])
def test_a_manifest_of_wrong_types_is_one_line(tmp_path, manifest, pattern):
    _write(tmp_path)
    path = tmp_path / dataset.MANIFEST
    path.write_text(json.dumps(dict(json.loads(path.read_text()), **manifest)))
    message = _one_line_error(lambda: dataset.read_dataset(tmp_path), pattern)
    assert message.startswith(f"dataset manifest '{path}'")
    # the writer reads the same manifest before adding a shard
    _one_line_error(lambda: _write(tmp_path, (1, 2)), pattern)
    for text in ("[1, 2]", "[" * 100_000 + "]" * 100_000):
        path.write_text(text)
        _one_line_error(lambda: dataset.read_dataset(tmp_path),
                        r"is not a JSON object|nests too deeply")


def test_a_shard_bigger_than_the_limit_is_refused_before_its_arrays_are_read(tmp_path,
                                                                             monkeypatch):
    _write(tmp_path, n=8192)       # its members past the headers' allowance (packed rows)
    monkeypatch.setattr(limits, "MAX_SHARD_SEGMENTS", 4)
    read = []
    monkeypatch.setattr(np.lib.format, "read_array",
                        lambda *args, **kwargs: read.append(1) or pytest.fail("array read"))
    _one_line_error(lambda: dataset.read_dataset(tmp_path),
                    r"unpacks to [\d,]+ bytes, more than the limit [\d,]+ \(4 segments")
    assert not read


def _forge_member(npz, name, shape, data=b""):
    """Replaces member ``name``.npy of ``npz`` with an npy header claiming ``shape`` (float32)
    and the bytes ``data``."""
    with zipfile.ZipFile(npz) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buffer, {"descr": "<f4", "fortran_order": False, "shape": shape})
    members[f"{name}.npy"] = buffer.getvalue() + data
    with zipfile.ZipFile(npz, "w") as archive:
        for member, content in members.items():
            archive.writestr(member, content)


def test_an_array_header_claiming_absurd_rows_is_one_line_not_a_memory_error(tmp_path):
    shard = _write(tmp_path)
    _forge_member(shard.with_suffix(".npz"), "p0", (10**12, 3), b"\0" * 48)
    _one_line_error(lambda: dataset.read_dataset(tmp_path),
                    r"array 'p0' claims shape \(1000000000000, 3\) \(12,000,000,000,000 bytes\)"
                    r", its member holds 48")
    _forge_member(shard.with_suffix(".npz"), "p0", (4, 3), b"\0" * 48)   # honest again
    assert dataset.read_dataset(tmp_path)[0].segments == 4


# --------------------------------------------------------------------------- the readers

HEADER_READ = re.compile(r"\bheader(\[|\.get\()")
HEADER_MODULE = "vdnif_addon/training/header.py"


def string_key_reads(repo):
    """'path:line: text' of each string-key read of a dataset header (``header[...]``,
    ``header.get(...)``) in the extension's and the tools' sources, but for the header's
    own module."""
    return matching_lines(repo, HEADER_READ, HEADER_MODULE)


def test_no_reader_takes_the_dataset_header_by_string_keys():
    assert string_key_reads(REPO) == []


def test_the_header_read_scan_finds_a_planted_read(tmp_path):
    for folder in ("vdnif_addon/training", "tools"):
        (tmp_path / folder).mkdir(parents=True)
    (tmp_path / HEADER_MODULE).write_text('object = header["object"]\n')     # its own: fine
    (tmp_path / "tools" / "planted.py").write_text(
        'size = merged_header["grid"]\nmode = header.get("mode")\n')
    (tmp_path / "viewer.py").write_text('h = header["voxel_size"]\n')
    assert string_key_reads(tmp_path) == ['tools/planted.py:2: mode = header.get("mode")',
                                          'viewer.py:1: h = header["voxel_size"]']
