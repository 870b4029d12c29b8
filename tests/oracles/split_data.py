"""The training data's split as it was before it wrote each column once: every shard
concatenated, converted, then masked by the held-out poses (or, with one pose, rays). The
oracle of ``training.data.split_data``'s rows, their order and their dtypes."""

import numpy as np
import torch

from vdnif_addon.training.data import FIELDS, RAY_FIELDS, held_out_rays, split_poses


def split_data(shards, config, heads, group, view_from=None):
    """(training rows, held-out rows, held-out calibration-view rows, held-out poses) of
    ``shards`` in one process; rays numbered ``view_from`` and up are the calibration
    view's."""
    keys = [key for key in FIELDS
            if (key != "albedo" or heads.albedo) and (key != "material" or heads.material)]
    data = {key: torch.from_numpy(np.concatenate([np.asarray(shard[key]) for shard in shards]))
            .to(FIELDS[key][0]) for key in keys}
    val_poses = split_poses(data["pose"], config.val_fraction, config.seed, group)
    held_out = (torch.isin(data["pose"], torch.tensor(val_poses, dtype=torch.int64))
                if val_poses else held_out_rays(data["ray"], config.val_fraction, config.seed))
    view = (data["ray"] >= view_from if view_from is not None
            else torch.zeros_like(held_out))
    train = {key: value[~held_out & ~view] for key, value in data.items()
             if key not in RAY_FIELDS}
    return (train, {key: value[held_out & ~view] for key, value in data.items()},
            {key: value[held_out & view] for key, value in data.items()}, val_poses)
