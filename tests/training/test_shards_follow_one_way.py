"""The shards of one dataset (written by several processes, each choosing how the voxel
corners follow the mesh) must all follow it one way: a model records one."""

import numpy as np
import pytest
from dataset_headers import header_dict

from vdnif_addon.errors import VDNIFError
from vdnif_addon.training import dataset
from vdnif_addon.training.header import DatasetHeader


def _write(folder, pose_range, **changes):
    name = f"shard-{pose_range[0]:06d}-{pose_range[1]:06d}"
    records = {key: np.zeros((4, *shape), dtype)
               for key, (dtype, shape) in dataset.ARRAYS.items()}
    records["pose"][:] = pose_range[0]
    header = dict(header_dict(pose_range=pose_range, segments=4), **changes)
    dataset.write_shard(folder, name, records, DatasetHeader.from_dict(header, "test"))


def test_shards_that_follow_two_ways_are_refused(tmp_path):
    _write(tmp_path, (0, 1))
    _write(tmp_path, (1, 2), corners_follow="evaluated surface")
    with pytest.raises(VDNIFError) as caught:
        dataset.read_dataset(tmp_path)
    message = str(caught.value)
    assert "\n" not in message and "shard-000001-000002.json" in message
    assert "evaluated surface" in message and "armature copy" in message


def test_shards_that_follow_one_way_read_as_it(tmp_path):
    for pose_range in ((0, 1), (1, 2)):
        _write(tmp_path, pose_range, corners_follow="evaluated surface")
    assert dataset.read_dataset(tmp_path)[0].header.corners_follow == "evaluated surface"
