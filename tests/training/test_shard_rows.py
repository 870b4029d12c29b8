"""A shard's rows checked against their own points (``shard_rows.check_lengths``), chunk by
chunk: a bad row past the first chunk is found and named by its row in the shard."""

import pathlib

import numpy as np
import pytest

from vdnif_addon.errors import VDNIFError
from vdnif_addon.training import shard_rows


def rows(count, extent=2.0, seed=0):
    rng = np.random.default_rng(seed)
    p0 = rng.random((count, 3)).astype(np.float32)
    p1 = (p0 + 0.01 * rng.normal(size=(count, 3))).astype(np.float32)
    normal = rng.normal(size=(count, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    rest = np.linalg.norm(p1.astype(np.float64) - p0, axis=1) * extent
    return {"p0": p0, "p1": p1, "rest_len": rest.astype(np.float32),
            "seg_len": np.ones(count, np.float32), "t0": np.zeros(count, np.float32),
            "hit": (np.arange(count) % 3 == 0).astype(np.uint8),
            "normal": normal.astype(np.float32)}


def test_rows_that_agree_with_their_points_pass():
    shard_rows.check_lengths(pathlib.Path("s.npz"), rows(3 * shard_rows._CHECK_ROWS + 7), 2.0)


@pytest.mark.parametrize("chunk", [0, 2])
def test_a_bad_rest_length_in_any_chunk_is_named_by_its_row(chunk):
    arrays = rows(3 * shard_rows._CHECK_ROWS + 7)
    row = chunk * shard_rows._CHECK_ROWS + 5
    arrays["rest_len"][row] *= 1.01
    with pytest.raises(VDNIFError, match=f"array 'rest_len' row {row} holds "):
        shard_rows.check_lengths(pathlib.Path("s.npz"), arrays, 2.0)


def test_a_hits_normal_off_unit_length_past_the_first_chunk_is_found():
    arrays = rows(3 * shard_rows._CHECK_ROWS + 7)
    arrays["normal"][3 * (shard_rows._CHECK_ROWS + 2)] *= 1.5   # hit number _CHECK_ROWS + 2
    arrays["normal"][3 * shard_rows._CHECK_ROWS + 1] *= 2.0     # not a hit: not checked
    with pytest.raises(VDNIFError, match="has a hit's normal of length 1.5, not 1"):
        shard_rows.check_lengths(pathlib.Path("s.npz"), arrays, 2.0)
