"""Model bytes per scene: trains a one-step model of each demo scene at its recipe resolution
and of a thin rod (a cylinder 1/100 of its length across, under a procedural armature) at
two resolutions, through ``batch.py -- train`` with a small dataset (2 poses, 1,024 rays a
pose), and reports each file's bytes, its occupied voxels and its tables' sizes (2^T of the
encoder's grid and of the normal field's). The bytes depend only on the network's shape, so
one training step is as good as a finished model for them. ``--batch`` runs another
checkout's ``batch.py`` (the sizes before a change); ``--json`` is checked by the output rule
before the first training.

    python tools/model_bytes.py --json out/model-bytes.json [--batch OTHER/vdnif_addon/batch.py]
"""

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdnif_addon.model.model_file import load_model  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402

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


def write_rod(path, radius=ROD_RADIUS, sides=12):
    """A closed cylinder along z, ``radius`` across a length of 1, as an OBJ file."""
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    lines = [f"v {radius * np.cos(a):.6f} {radius * np.sin(a):.6f} {z}"
             for z in (0.0, 1.0) for a in angles]
    lines += ["v 0 0 0", "v 0 0 1"]
    for i in range(sides):
        j = (i + 1) % sides
        a, b, c, d = i + 1, j + 1, sides + i + 1, sides + j + 1      # OBJ counts from 1
        lines += [f"f {a} {b} {d} {c}", f"f {2 * sides + 1} {b} {a}",
                  f"f {2 * sides + 2} {c} {d}"]
    path.write_text("\n".join(lines) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="write the figures here")
    parser.add_argument("--batch", type=pathlib.Path, default=ROOT / "vdnif_addon" / "batch.py",
                        help="the batch.py that trains (default: this checkout's)")
    args = parser.parse_args()
    check_output_file(args.json, "--json", "json")        # the output rule, before the runs
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
            rows.append({"scene": name, "bytes": model.stat().st_size,
                         "resolution": metadata.grid.resolution,
                         "occupied_voxels": metadata.grid.occupied_voxels,
                         "log2_table_size": config.log2_table_size,
                         "normal_log2_table_size": config.normal_log2_table_size})
            print(f"{name}: {rows[-1]['bytes']:,} bytes, {metadata.grid.occupied_voxels} "
                  f"voxels, tables 2^{config.log2_table_size} and "
                  f"2^{config.normal_log2_table_size}", flush=True)
    write_json_atomic(args.json, stamp({"format": FORMAT, "batch": str(args.batch),
                                        "rows": rows}), "model bytes", indent=1)


if __name__ == "__main__":
    main()
