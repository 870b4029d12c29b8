"""Model bytes per scene: trains a one-step model of each demo scene at its recipe resolution
and of a thin rod (a cylinder 1/100 of its length across, under a procedural armature) at
two resolutions, through ``batch.py -- train`` with a small dataset (2 poses, 1,024 rays a
pose), and reports each file's bytes, its occupied voxels, its tables' sizes (2^T of the
encoder's grid and of the normal field's) and how many vertices each grid's finest level can
read in the occupied voxels, counted exactly on the rest mesh's grid (the tables hold
2^T). The bytes depend only on the network's shape, so one training step is as good as a
finished model for them. ``--batch`` runs another checkout's ``batch.py`` (the sizes before
a change); ``--json`` is checked by the output rule before the first training.

    python tools/model_bytes.py --json out/model-bytes.json [--batch OTHER/vdnif_addon/batch.py]
"""

import argparse
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.blender.mesh_files import import_mesh  # noqa: E402
from vdnif_addon.blender.read_mesh import read_rest_mesh  # noqa: E402
from vdnif_addon.blender.scenes import demo_scene  # noqa: E402
from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.geometry.voxels import build_grid  # noqa: E402
from vdnif_addon.model.model_file import load_model  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402
from vdnif_addon.settings import level_resolutions  # noqa: E402

FORMAT = "vdnif-model-bytes"
"""The figures' format mark: the output rule lets ``--json`` replace only the tool's own file."""

ROD_RADIUS = 0.005
"""The thin rod's radius, its length 1: a cable or a strand, the thinnest a rig deforms."""

RUNS = (("arm", ["--scene", "arm", "--resolution", "recipe"]),
        ("lattice", ["--scene", "lattice", "--resolution", "recipe"]),
        ("spot", ["--scene", "spot", "--resolution", "recipe"]),
        ("bunny", ["--scene", "bunny", "--resolution", "recipe"]),
        ("thin rod, 32", ["--mesh", "{rod}", "--rig", "armature", "--resolution", "32"]),
        ("thin rod, 12", ["--mesh", "{rod}", "--rig", "armature", "--resolution", "12"]))
"""(row, the scene options of ``train``): the rod at 12 voxels occupies about 50."""

SMALL = ["--poses", "2", "--rays-per-pose", "1024", "--steps", "1", "--device", "cpu"]


def rod_mesh(radius=ROD_RADIUS, sides=12):
    """The thin rod as (vertices, triangles): a closed cylinder along z, ``radius`` across a
    length of 1."""
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], 1)
    vertices = np.concatenate([np.c_[ring, np.zeros(sides)], np.c_[ring, np.ones(sides)],
                               [[0, 0, 0], [0, 0, 1]]])
    triangles = []
    for i in range(sides):
        j = (i + 1) % sides
        triangles += [[i, j, sides + j], [i, sides + j, sides + i], [2 * sides, j, i],
                      [2 * sides + 1, sides + i, sides + j]]
    return vertices, np.array(triangles)


def read_vertices(grid, resolution):
    """How many vertices of a level ``resolution`` cells across points in ``grid``'s occupied
    voxels can read: those of every level cell a voxel overlaps, counted once."""
    across = int(grid.dims.max())
    low = np.floor(grid.cells / across * resolution).astype(np.int64)
    high = np.minimum(np.floor((grid.cells + 1) / across * resolution).astype(np.int64),
                      resolution - 1) + 1
    side = resolution + 1
    keys = []
    for lo, hi in zip(low, high):
        axes = np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij")
        keys.append((axes[0] + side * (axes[1] + side * axes[2])).ravel())
    return len(np.unique(np.concatenate(keys)))


def write_rod(path):
    """The thin rod as an OBJ file."""
    vertices, triangles = rod_mesh()
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
    path.write_text("\n".join(lines) + "\n")


def rest_grid(options, rod, resolution):
    """The occupied voxels the run's model trained on: its rest mesh's grid, the mesh read
    as ``train`` reads it."""
    if "--scene" in options:
        obj = demo_scene(options[options.index("--scene") + 1])
    else:
        obj = import_mesh(rod)
    mesh = read_rest_mesh(obj)
    return build_grid(mesh.vertices, mesh.triangles, resolution)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="write the figures here")
    parser.add_argument("--batch", type=pathlib.Path, default=ROOT / "vdnif_addon" / "batch.py",
                        help="the batch.py that trains (default: this checkout's)")
    args = parser.parse_args()
    check_output_file(args.json, "--json", "json")        # the output rule, before the runs
    if not args.batch.is_file():
        raise VDNIFError(f"--batch '{args.batch}' is not a file")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        rod = pathlib.Path(scratch) / "rod.obj"
        write_rod(rod)
        for name, options in RUNS:
            model = pathlib.Path(scratch) / f"{len(rows)}.vdnif"
            command = [sys.executable, str(args.batch), "--", "train",
                       *[option.format(rod=rod) for option in options], *SMALL,
                       "--out", str(model)]
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            _, metadata = load_model(model)
            config = metadata.network_config
            grid = rest_grid(options, rod, metadata.grid.resolution)
            if len(grid.cells) != metadata.grid.occupied_voxels:
                raise VDNIFError(f"{name}: the rest grid has {len(grid.cells)} voxels, the "
                                 f"model {metadata.grid.occupied_voxels}")
            finest = {key: level_resolutions(levels, config.base_resolution, config.growth)[-1]
                      for key, levels in (("encoder", config.levels),
                                          ("normal", config.normal_levels))}
            rows.append({"scene": name, "bytes": model.stat().st_size,
                         "resolution": metadata.grid.resolution,
                         "occupied_voxels": metadata.grid.occupied_voxels,
                         "log2_table_size": config.log2_table_size,
                         "normal_log2_table_size": config.normal_log2_table_size,
                         "finest_resolution": finest,
                         "finest_reads": {key: read_vertices(grid, res)
                                          for key, res in finest.items()}})
            print(f"{name}: {rows[-1]['bytes']:,} bytes, {metadata.grid.occupied_voxels} "
                  f"voxels, tables 2^{config.log2_table_size} and "
                  f"2^{config.normal_log2_table_size}; the finest levels read "
                  f"{rows[-1]['finest_reads']}", flush=True)
    write_json_atomic(args.json, stamp({"format": FORMAT, "batch": str(args.batch),
                                        "rows": rows}), "model bytes", indent=1)


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=(VDNIFError, subprocess.CalledProcessError),
                 prefix="model_bytes: error: ")
