"""What limits the predicted albedo: the network, or where it puts the hit? Fits an albedo
field of the rest-space hit point (a hash grid and a small MLP, nothing else) to a dataset's
hits and measures PSNR on its held-out poses' hits, at the true hit point, at the hit point
the model predicts, and at the true one moved along the ray by Gaussian noise of a few
tenths of a voxel; beside them, the PSNR of the model's own albedo on the same hits (its
head over the segment, or its field at the hit it places: ``albedo_mode``).

    python vdnif_addon/batch.py -- dataset --scene spot --out out/spot-data
    python vdnif_addon/batch.py -- train --data out/spot-data --out out/spot.vdnif
    python tools/albedo_ceiling.py --data out/spot-data --model out/spot.vdnif

Without ``--model`` only the field's figures are printed. ``--shell S`` fits the field at
points moved off the surface along its rest normal by N(0, S voxels), each with its hit's
albedo: whether an albedo field that is constant near the surface tolerates a misplaced hit.

Held out: the last ``--held-out`` poses of the dataset (the model trained on them too unless
its training held them out: the figures compare the two on the same hits either way).
"""

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch import nn  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.model.encoding import HashGrid  # noqa: E402
from vdnif_addon.model.model_file import load_model  # noqa: E402
from vdnif_addon.training.dataset import read_dataset  # noqa: E402

SHIFTS = (0.02, 0.05, 0.1, 0.2, 0.4)
"""Standard deviations, in voxels, of the noise the true hit point is moved by."""


def psnr(predicted, reference):
    return float(-10 * np.log10(np.mean((predicted - reference) ** 2)))


def tensor(array):
    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=pathlib.Path, required=True)
    parser.add_argument("--model", type=pathlib.Path,
                        help="a model trained on the dataset (without: the field alone)")
    parser.add_argument("--held-out", type=int, default=4)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--levels", type=int, default=2)
    parser.add_argument("--log2-table-size", type=int, default=20)
    parser.add_argument("--shell", type=float, default=0.0,
                        help="fit the field at points moved along the rest-space normal by "
                             "N(0, SHELL voxels), each with its true hit's albedo")
    args = parser.parse_args()
    if not 0 <= args.shell < float("inf"):
        raise VDNIFError(f"--shell must be a finite number of voxels >= 0, got {args.shell}")
    torch.manual_seed(0)
    network = load_model(args.model)[0] if args.model else None
    merged, shards = read_dataset(args.data)
    header = merged.header
    if not header.heads.albedo:
        raise VDNIFError(f"dataset '{args.data}' has no albedo head: it needs a textured or "
                         "multi-coloured object")
    if network and "albedo" not in network.head_sizes:
        raise VDNIFError(f"model '{args.model}' has no albedo head: train it on '{args.data}'")
    data = {key: np.concatenate([shard[key] for shard in shards]) for key in shards[0]}
    hit = data["hit"] > 0
    point = data["p0"] + data["hit_frac"][:, None] * (data["p1"] - data["p0"])
    last = data["pose"].max() - args.held_out
    held, train = hit & (data["pose"] > last), hit & (data["pose"] <= last)
    reference = data["albedo"][held]
    p0, p1 = data["p0"][held], data["p1"][held]
    print(f"hits: {train.sum():,} to fit, {held.sum():,} held out (poses > {last})")
    # The dataset's points are normalized rest coordinates (``VoxelGrid.normalize``): one
    # voxel is the voxel size over the grid's extent there.
    voxel = header.grid.voxel_size / header.grid.extent

    if network:
        with torch.inference_mode():
            predicted = network.predict(tensor(p0), tensor(p1),
                                        tensor(data["rest_len"][held]), header.voxel_size)
        own = psnr(predicted["albedo"].numpy(), reference)
        print(f"the model's albedo ({network.config.albedo_mode}): {own:.2f} dB")

    grid = HashGrid(args.levels, 64, 2.0, args.log2_table_size, 2)
    mlp = nn.Sequential(nn.Linear(grid.output_dim, 64), nn.ReLU(), nn.Linear(64, 64),
                        nn.ReLU(), nn.Linear(64, 3))
    optimizer = torch.optim.Adam([{"params": grid.parameters(), "lr": 1e-2},
                                  {"params": mlp.parameters(), "lr": 1e-3}], eps=1e-15)
    points, albedo = tensor(point[train]), tensor(data["albedo"][train])
    normals = tensor(data["normal"][train])
    for _ in range(args.steps):
        batch = torch.randint(0, len(points), (16384,))
        at = points[batch]
        if args.shell > 0:
            at = at + torch.randn(len(batch), 1) * (args.shell * voxel) * normals[batch]
        loss = (torch.sigmoid(mlp(grid(at))) - albedo[batch]).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    def field(at):
        with torch.inference_mode():
            return torch.sigmoid(mlp(grid(tensor(at)))).numpy()

    print(f"field at the true hit point: {psnr(field(point[held]), reference):.2f} dB")
    if network:
        guess = p0 + predicted["fraction"].numpy()[:, None] * (p1 - p0)
        print(f"field at the model's hit point: {psnr(field(guess), reference):.2f} dB")
    direction = (p1 - p0) / np.linalg.norm(p1 - p0, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    for sigma in SHIFTS:
        shift = rng.normal(0.0, sigma, len(reference)) * voxel
        moved = point[held] + shift[:, None] * direction
        print(f"field at the true hit point moved by N(0, {sigma} voxel) along the ray: "
              f"{psnr(field(moved), reference):.2f} dB")


if __name__ == "__main__":
    try:
        main()
    except VDNIFError as error:
        sys.exit(f"albedo_ceiling: error: {error}")
