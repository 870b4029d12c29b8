"""How the voxel corners of armature and lattice rigs follow them in training: the embedding
error (embedded against true reference: distance MAE in object units, hit mismatch) of the
copied modifiers and of the surface binding on the development poses the choice is made on
(``blender/follow_choice.py``), the choice, and its seconds, on the arm and lattice demo
scenes and a flat slab in a lattice fitted tightly around it (``tools/resolution_meshes.py``),
each at the recipe's resolution. Writes JSON (marked as the tool's and checked by the output
rule before any scene is built: it replaces only a file the tool wrote) and prints the
Markdown table; no network is trained.

    python tools/corners_follow_choice.py --json docs/results/corners-follow-choice.json
"""

import argparse
import os
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402  isort: skip  (Blender's modules come with it)
from resolution_meshes import thin_lattice_slab  # noqa: E402

from vdnif_addon.blender.follow_choice import choose_follow  # noqa: E402
from vdnif_addon.blender.resolution import recipe_resolution  # noqa: E402
from vdnif_addon.blender.scenes import demo_scene  # noqa: E402
from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.geometry.capture import ARMATURE_COPY, EVALUATED_SURFACE  # noqa: E402
from vdnif_addon.kernels.runtime import cpu_description  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.pose_sets import PoseSpec  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402
from vdnif_addon.settings import SUGGEST_POSES, SUGGEST_VIEW_SIZE  # noqa: E402

FORMAT = "vdnif-corners-follow-choice"
"""The results' format mark: the output rule lets ``--json`` replace only the tool's own file."""
SCENES = {"arm (armature)": lambda: demo_scene("arm"),
          "lattice (Suzanne)": lambda: demo_scene("lattice"),
          "slab in a tightly fitted lattice": thin_lattice_slab}


def measure(name, build):
    """One row: the scene's choice at the recipe's resolution, as training makes it."""
    bpy.ops.wm.read_homefile(use_empty=True)
    obj = build()
    resolution = recipe_resolution(obj)
    load = os.getloadavg()[0]
    choice = choose_follow(obj, resolution, PoseSpec())
    return {"scene": name, "resolution": resolution, "errors": choice.errors,
            "chosen": choice.follow, "seconds": choice.seconds, "load_before": load}


def markdown(rows):
    def cell(row, follow):
        figures = row["errors"][follow]
        return (f"{figures['embedding_error']:.2g} ({100 * figures['hit_mismatch']:.2g} %)")

    lines = ["| rig | resolution | copied modifiers | surface binding | chosen | seconds |",
             "| --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {row['scene']} | {row['resolution']} | {cell(row, ARMATURE_COPY)} | "
              f"{cell(row, EVALUATED_SURFACE)} | {row['chosen']} | {row['seconds']:.1f} |"
              for row in rows]
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, type=pathlib.Path)
    args = parser.parse_args()
    check_output_file(args.json, "--json", "json")      # the output rule, before any scene
    cpu, _ = cpu_description()     # as every results JSON names it
    rows = [measure(name, build) for name, build in SCENES.items()]
    results = {"format": FORMAT, "command": " ".join(["python", *sys.argv]), "cpu": cpu,
               "cpus": os.cpu_count(), "blender": bpy.app.version_string,
               "poses": SUGGEST_POSES, "view": SUGGEST_VIEW_SIZE,
               "note": "seconds on a machine shared with other sessions' work (loaded; "
                       "load_before: the 1-minute load average before each scene)",
               "rows": rows}
    write_json_atomic(args.json, stamp(results, with_machine=True), "--json", indent=1)
    print(markdown(rows))


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=VDNIFError, prefix="corners_follow_choice: error: ")
