"""safe_io: fresh exclusive temporary files renamed into place, no write through a symlink,
nothing replaced by a failing write, strict JSON; the dataset folder's manifest."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO
from dataset_headers import header_dict

from vdnif_addon.errors import VDNIFError
from vdnif_addon.output_rule import OUTPUT_MARK
from vdnif_addon.safe_io import (
    FILE_STEM_LIMIT,
    atomic_path,
    check_output_file,
    check_output_folder,
    exclusive_lock,
    file_stem,
    write_bytes_atomic,
    write_json_atomic,
)
from vdnif_addon.training import dataset
from vdnif_addon.training.header import DatasetHeader


def _listing(folder):
    return sorted(os.listdir(folder))


def test_a_symlink_at_the_target_is_replaced_not_written_through(tmp_path):
    victim = tmp_path / "victim.json"           # a file VDNIF wrote: replaceable, by its mark
    victim.write_text('{"format": "vdnif-report"}\n')
    (tmp_path / "c.json").symlink_to(victim)
    write_json_atomic(tmp_path / "c.json", {"a": 1})
    assert victim.read_text() == '{"format": "vdnif-report"}\n'
    assert not (tmp_path / "c.json").is_symlink()
    assert json.loads((tmp_path / "c.json").read_text()) == {"a": 1}


def test_planted_symlinks_at_the_old_temporary_names_are_left_alone(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    for name in ("c.json.tmp", ".c.json.partial", ".c.json.tmp", ".c.partial.json"):
        (tmp_path / name).symlink_to(victim)
    write_json_atomic(tmp_path / "c.json", {"a": 1})
    assert victim.read_text() == "precious\n"
    assert json.loads((tmp_path / "c.json").read_text()) == {"a": 1}


def test_a_failing_writer_leaves_the_target_and_no_temporary_file(tmp_path):
    target = tmp_path / "image.png"
    target.write_bytes(b"old")
    (tmp_path / OUTPUT_MARK).write_text("")       # a folder of VDNIF's outputs
    with pytest.raises(RuntimeError, match="writer failed"):
        with atomic_path(target, "image") as temporary:
            assert temporary.endswith(".png") and os.path.dirname(temporary) == str(tmp_path)
            with open(temporary, "wb") as file:
                file.write(b"half")
            raise RuntimeError("writer failed")
    assert target.read_bytes() == b"old"
    assert _listing(tmp_path) == sorted([OUTPUT_MARK, "image.png"])


def test_non_finite_json_is_refused_naming_the_figure(tmp_path):
    target = tmp_path / "r.json"
    target.write_text("{}\n")
    with pytest.raises(VDNIFError, match=r"'vs_true.albedo_psnr' is not a finite number"):
        write_json_atomic(target, {"vs_true": {"albedo_psnr": float("nan")}})
    assert target.read_text() == "{}\n" and _listing(tmp_path) == ["r.json"]


def test_written_files_are_not_private(tmp_path):
    write_bytes_atomic(tmp_path / "a.bin", b"x")
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o666 & ~mask


def test_output_places_are_checked_before_work(tmp_path):
    (tmp_path / "file.txt").write_text("x")
    (tmp_path / "folder").mkdir()
    check_output_file(tmp_path / "new" / "deeper" / "r.json")          # creatable
    check_output_folder(tmp_path / "new" / "out")
    with pytest.raises(VDNIFError, match="is a folder, not a file"):
        check_output_file(tmp_path / "folder")
    with pytest.raises(VDNIFError, match="file.txt' is not a folder"):
        check_output_file(tmp_path / "file.txt" / "r.json")
    with pytest.raises(VDNIFError, match="exists and is not a folder"):
        check_output_folder(tmp_path / "file.txt")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_folder_is_refused(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(VDNIFError, match="is not writable"):
            check_output_file(folder / "r.json")
    finally:
        folder.chmod(0o755)


def _records(n=4, pose=0):
    records = {name: np.zeros((n, *shape), dtype)
               for name, (dtype, shape) in dataset.ARRAYS.items()}
    records["pose"][:] = pose
    return records


def _header(name="Ball", seed=0, pose_range=(0, 1)):
    return DatasetHeader.from_dict(header_dict(name, seed, pose_range, segments=4), "test")


def test_an_exclusive_lock_has_one_holder_until_it_is_closed_or_its_process_ends(tmp_path):
    path = tmp_path / "point-0.lock"
    first = exclusive_lock(path)
    assert first is not None
    assert exclusive_lock(path) is None            # held: another open file cannot take it
    with first:
        pass
    second = exclusive_lock(path)                  # closing released it
    assert second is not None
    second.close()
    # a process that holds it and is killed leaves no stale lock
    script = (f"import sys; sys.path.insert(0, {str(REPO)!r}); "
              "from vdnif_addon.safe_io import exclusive_lock; "
              f"lock = exclusive_lock({str(path)!r}); print(lock is not None, flush=True); "
              "import time; time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "True"
        assert exclusive_lock(path) is None
    finally:
        holder.kill()
        holder.wait()
    third = exclusive_lock(path)
    assert third is not None
    third.close()
    assert path.exists()                            # the file stays; only the lock goes


def test_a_dataset_folder_refuses_a_shard_of_another_object_or_seed(tmp_path):
    dataset.write_shard(tmp_path, "shard-000000-000001", _records(), _header())
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert dataset.MANIFEST in before
    for header in (_header(name="Cube"), _header(seed=3)):
        with pytest.raises(VDNIFError, match="holds shards of object 'Ball'"):
            dataset.write_shard(tmp_path, "shard-000000-000001", _records(), header)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    dataset.write_shard(tmp_path, "shard-000001-000002", _records(pose=1),
                        _header(pose_range=(1, 2)))                    # the same object: fine
    merged, shards = dataset.read_dataset(tmp_path)
    assert len(shards) == 2 and merged.segments == 8


@pytest.mark.parametrize("name, stem", [
    ("Hero", "Hero"), ("../../../tmp/x/evil", "_.._.._tmp_x_evil"), ("/etc/passwd", "_etc_passwd"),
    ("..", "object"), ("", "object"), ("a b:c", "a_b_c"), ("x" * 300, "x" * FILE_STEM_LIMIT)])
def test_a_name_becomes_one_file_name_component(name, stem):
    assert file_stem(name) == stem
    assert os.sep not in file_stem(name) and not file_stem(name).startswith(".")


@pytest.mark.parametrize("path", ["out/evaldir/", "out/.", "out/.."])
def test_an_output_file_path_that_names_a_folder_is_refused(tmp_path, path):
    with pytest.raises(VDNIFError, match="names a folder, not a file"):
        check_output_file(str(tmp_path) + "/" + path)
    assert list(tmp_path.iterdir()) == []
