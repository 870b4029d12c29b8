"""How a development mesh's separate parts move against the surface they touch under the
procedural armature, and what the voxel embedding makes of it.

Blender's automatic weights (bone heat) weight a mesh of several separate shells (Suzanne's
eyes in their sockets) shell by shell, so a part can follow the bones otherwise than the
surface it touches: in a bend the two slide apart in the true mesh, while one voxel gives
both one motion. The procedural armature therefore weights a small piece that touches the
largest one as that piece's nearest vertex (``blender.scenes.follow_riders``). Per riding
part (``blender.pieces.riders``): its vertices within ``--near`` object units of the largest
part and the difference of their normalized bone weights, as bone heat leaves them, from the
nearest vertex there (the sum over bones of the absolute differences: 0 alike, 2 on other
bones). Then the embedding alone (``references --secondary``, no network, 8 test poses at
256x256) of the rig with bone heat's weights alone and of the procedural rig, whose riding
parts are weighted as the surface they touch, at each ``--resolution``:

    python tools/separate_parts.py --mesh monkey --resolution 96 --resolution 192 \\
        --json docs/results/separate-parts.json
"""

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import numpy as np  # noqa: E402
from dev_mesh_study import MESHES_TOOL, mesh_table  # noqa: E402
from resolution_table import BATCH  # noqa: E402

from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.geometry.framing import components  # noqa: E402

REFERENCES = ["--poses", "8", "--width", "256", "--height", "256", "--secondary"]
VARIANTS = ("bone heat alone", "riding parts weighted as the surface they touch")
FIGURES = ("distance_mae", "distance_mae_voxels", "normal_error_deg", "hit_iou",
           "shadow_false_lit_rate", "shadow_false_shadow_rate", "ao_mae")


def parts(vertex_count, triangles):
    """(V,) label of each vertex's connected piece (``geometry.framing.components``), ranked
    by vertex count: 0 for the piece with the most vertices."""
    _, piece = np.unique(components(vertex_count, triangles), return_inverse=True)
    order = np.argsort(-np.bincount(piece), kind="stable")
    return np.argsort(order)[piece]


def mesh_triangles(obj):
    """(T, 3) vertex indices of the triangles of mesh object ``obj``."""
    obj.data.calc_loop_triangles()
    return np.array([t.vertices[:] for t in obj.data.loop_triangles], np.int64).reshape(-1, 3)


def rig_files(obj_path, folder, near):
    """Rigs the mesh at ``obj_path`` with the procedural armature; writes it with bone heat's
    weights alone and as the procedural rig weights it; (the two .blend paths, the riding
    parts' figures)."""
    import bpy

    from vdnif_addon.blender.mesh_files import import_mesh
    from vdnif_addon.blender.pieces import normalized, riders
    from vdnif_addon.blender.scenes import add_rig, bone_weights, chain_bones, follow_riders

    bpy.ops.wm.read_homefile(use_empty=True)
    obj = add_rig(import_mesh(str(obj_path)), "armature", riders_follow=False)
    vertices = np.array([v.co for v in obj.data.vertices])
    label = parts(len(vertices), mesh_triangles(obj))
    bones = chain_bones(obj)
    weights = normalized(bone_weights(obj))
    riding, source = riders(obj)
    distance = np.linalg.norm(vertices[riding] - vertices[source], axis=1)
    figures = []
    for part in np.unique(label[riding]):
        inside = label[riding] == part
        close = distance[inside] < near
        members, sources = riding[inside][close], source[inside][close]
        difference = np.abs(weights[members] - weights[sources]).sum(1)
        figures.append({
            "vertices": int(inside.sum()), "centre": vertices[riding[inside]].mean(0).tolist(),
            "near_vertices": int(close.sum()),
            "weight_difference_median": float(np.median(difference)) if close.any() else None,
            "weight_difference_max": float(difference.max()) if close.any() else None,
            "weights": dict(zip(bones, weights[members].mean(0).tolist())),
            "touched_weights": dict(zip(bones, weights[sources].mean(0).tolist()))})
    paths = [folder / "bone-heat.blend", folder / "riders-follow.blend"]
    bpy.ops.wm.save_as_mainfile(filepath=str(paths[0]))
    follow_riders(obj)
    bpy.ops.wm.save_as_mainfile(filepath=str(paths[1]))
    return paths, figures


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", default="monkey", choices=tuple(mesh_table()),
                        help="the development mesh (default: monkey)")
    parser.add_argument("--resolution", type=int, action="append",
                        help="voxel resolution (repeatable; default 96)")
    parser.add_argument("--near", type=float, default=0.05,
                        help="count a riding part's vertices this close to the largest part")
    parser.add_argument("--json", type=pathlib.Path, required=True, help="write the figures")
    args = parser.parse_args(argv)
    if mesh_table()[args.mesh][0] != "armature":
        raise VDNIFError(f"'{args.mesh}' is rigged with a lattice, which has no bone weights")
    if not args.near > 0:
        raise VDNIFError(f"--near must be positive, got {args.near}")
    from vdnif_addon.cli.options import check_resolution
    from vdnif_addon.model.provenance import stamp
    from vdnif_addon.safe_io import write_json_atomic

    resolutions = args.resolution or [96]
    for resolution in resolutions:          # before minutes of references, not after
        check_resolution(resolution)
    runs = {}
    with tempfile.TemporaryDirectory(prefix="vdnif-parts-") as folder:
        folder = pathlib.Path(folder)
        subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(folder), "--mesh",
                        args.mesh], check=True, stdout=subprocess.DEVNULL)
        blends, figures = rig_files(folder / f"{args.mesh}.obj", folder, args.near)
        for variant, blend in zip(VARIANTS, blends):
            for resolution in resolutions:
                report = folder / "references.json"
                subprocess.run([*BATCH, "references", "--blend", str(blend), "--resolution",
                                str(resolution), *REFERENCES, "--json", str(report)],
                               check=True, stdout=subprocess.DEVNULL)
                error = json.loads(report.read_text())["embedded_vs_true"]
                runs[f"{variant}/{resolution}"] = {key: error[key] for key in FIGURES}
                print(f"{args.mesh}, {variant}, R {resolution}: distance MAE "
                      f"{error['distance_mae']:.3g}, false shadow "
                      f"{100 * error['shadow_false_shadow_rate']:.3g} %, false lit "
                      f"{100 * error['shadow_false_lit_rate']:.3g} %")
    for number, part in enumerate(figures, 1):
        print(f"riding part {number}: {part['vertices']} vertices, {part['near_vertices']} "
              f"near the largest part; weight difference there, bone heat alone, median "
              f"{part['weight_difference_median']}")
    write_json_atomic(args.json, stamp({
        "mesh": args.mesh, "rig": "armature", "near": args.near,
        "references": REFERENCES, "command": ["python", "tools/separate_parts.py", *argv],
        "parts": figures, "runs": runs}, with_machine=False))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:], errors=VDNIFError, prefix="separate_parts: error: ")
