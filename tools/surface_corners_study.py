"""Corners that follow the evaluated surface, beside today's copies of the armature: the
per-pose cost of moving the voxel corners on the arm demo scene (also with a Subdivision
Surface after its armature, bound to the cage and to the subdivided surface), and the voxel
embedding's own error (embedded vs true reference: distance MAE and hit IoU) on the small
rigs of ``tests/support/artist_rigs.py`` and their armature-only (lattice-only) twins, with
both ways of following where both apply; and beside them Blender's own Surface Deform
modifier on a helper object of the corners (bound to the mesh at rest, its default falloff),
the alternative the binding was measured against. Writes JSON (marked as the study's,
checked by the output rule before any scene is built and written atomically: it replaces only
a file the study wrote); no network is trained.

    python tools/surface_corners_study.py --json out/surface-corners.json \\
        [--poses 8] [--resolution 32] [--size 96]
"""

import argparse
import json
import os
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "support")]

import bpy  # noqa: E402  isort: skip  (Blender's modules come with it)
import artist_rigs  # noqa: E402
import numpy as np  # noqa: E402

from vdnif_addon.blender import deform  # noqa: E402
from vdnif_addon.blender.capture_scene import capture  # noqa: E402
from vdnif_addon.blender.pose_reader import PoseReader  # noqa: E402
from vdnif_addon.blender.poses import evaluation_spec, posed  # noqa: E402
from vdnif_addon.blender.read_mesh import deformers_disabled  # noqa: E402
from vdnif_addon.blender.scenes import demo_scene  # noqa: E402
from vdnif_addon.errors import VDNIFError  # noqa: E402
from vdnif_addon.geometry.capture import ARMATURE_COPY, EVALUATED_SURFACE  # noqa: E402
from vdnif_addon.kernels.runtime import cpu_description  # noqa: E402
from vdnif_addon.model.provenance import stamp  # noqa: E402
from vdnif_addon.pose_sets import PoseSpec  # noqa: E402
from vdnif_addon.posed.generate import reference_run  # noqa: E402
from vdnif_addon.safe_io import check_output_file, write_json_atomic  # noqa: E402

FIGURES = ("distance_mae", "distance_mae_voxels", "hit_iou", "false_negative_rate",
           "false_positive_rate", "normal_error_deg")
FORMAT = "vdnif-surface-corners"
"""The results' format mark: the output rule lets ``--json`` replace only the study's own file."""


SURFACE_DEFORM = "surface deform modifier"


class SurfaceDeformCorners:
    """The corners as the vertices of a helper object with a Surface Deform modifier whose
    target is ``obj`` (bound with ``obj``'s armature and lattice off: at rest), evaluated
    by Blender in each pose; quacks like ``deform.CornerDeformer``."""

    binding = None

    def __init__(self, obj, points):
        data = bpy.data.meshes.new(f"{obj.name} surface deform corners")
        data.vertices.add(len(points))
        data.vertices.foreach_set("co", points.astype("float32").ravel())
        self.helper = bpy.data.objects.new(data.name, data)
        bpy.context.scene.collection.objects.link(self.helper)
        self.helper.parent = obj
        modifier = self.helper.modifiers.new("Surface Deform", "SURFACE_DEFORM")
        modifier.target = obj
        with deformers_disabled(obj):
            with bpy.context.temp_override(object=self.helper, active_object=self.helper):
                bpy.ops.object.surfacedeform_bind(modifier=modifier.name)
            self.deformed()                   # the evaluation that binds
        if not modifier.is_bound:
            raise RuntimeError(f"Surface Deform did not bind the corners of '{obj.name}'")

    def deformed(self):
        evaluated = self.helper.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = evaluated.to_mesh()
        try:
            co = [0.0] * (3 * len(mesh.vertices))
            mesh.vertices.foreach_get("co", co)
        finally:
            evaluated.to_mesh_clear()
        return np.array(co, np.float64).reshape(-1, 3)

    def close(self):
        data = self.helper.data
        bpy.data.objects.remove(self.helper)
        bpy.data.meshes.remove(data)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _ms(seconds):
    return round(1000 * statistics.median(seconds), 3)


def _timed_pose(pose, work):
    """Seconds to put the scene in ``pose`` (Blender evaluates it) and run ``work``."""
    context = posed(pose)
    start = time.perf_counter()
    context.__enter__()
    try:
        work()
        return time.perf_counter() - start
    finally:
        context.__exit__(None, None, None)


def pose_costs(obj, resolution, count, cage_too=False):
    """Median milliseconds per pose: posing the scene without corners (``posing_ms``:
    Blender's evaluation of what it evaluates eagerly), and for each way of following the
    corners posing with them (the helper objects' evaluation included) and the difference
    (``corners_ms``); for the surface, its binding's arithmetic alone. The true mesh is not
    read: a neural pose does not need it."""
    captured = capture(obj, resolution, PoseSpec(count=count, seed=3), deform_corners=False)
    points = captured.grid.corner_positions()
    figures = {"object": obj.name, "corners": int(len(points)),
               "triangles": int(len(captured.mesh.triangles)), "poses": count}
    scene = []
    for pose in captured.poses:
        scene.append(_timed_pose(pose, lambda: None))
    figures["posing_ms"] = _ms(scene)
    ways = [(ARMATURE_COPY, True), (EVALUATED_SURFACE, True)] + (
        [(EVALUATED_SURFACE, False)] if cage_too else []) + [(SURFACE_DEFORM, False)]
    for follow, cage in ways:
        start = time.perf_counter()
        with (SurfaceDeformCorners(obj, points) if follow == SURFACE_DEFORM
              else deform.CornerDeformer(obj, points, follow, cage=cage)) as deformer:
            bind_s = time.perf_counter() - start
            whole, arithmetic = [], []
            for pose in captured.poses:
                whole.append(_timed_pose(pose, deformer.deformed))
                if deformer.binding is not None:
                    with posed(pose):
                        surface = deformer._posed_surface()
                        start = time.perf_counter()
                        deformer.binding.moved(*surface)
                        arithmetic.append(time.perf_counter() - start)
            name = follow if follow != EVALUATED_SURFACE else (
                f"{follow} ({'cage' if cage else 'subdivided surface'})")
            figures[name] = {"setup_s": round(bind_s, 4),
                             "posing_and_corners_ms": _ms(whole),
                             "corners_ms": round(_ms(whole) - figures["posing_ms"], 3),
                             "bound_vertices": (None if deformer.binding is None
                                                else deformer.binding.vertex_count)}
            if arithmetic:
                figures[name]["binding_arithmetic_ms"] = _ms(arithmetic)
    return figures


def embedding(obj, spec, resolution, size, follow):
    """The embedded vs true figures with the corners following as ``follow`` says (the
    Surface Deform modifier's corners put in a live reader's place)."""
    captured = capture(obj, resolution, spec, deform_corners=False,
                       follow=EVALUATED_SURFACE if follow == SURFACE_DEFORM else follow)
    source = obj
    if follow == SURFACE_DEFORM:
        source = PoseReader(obj, captured)
        source.deformer.close()
        source.deformer = SurfaceDeformCorners(obj, captured.grid.corner_positions())
    try:
        report = reference_run(source, captured, size, size)
    finally:
        if source is not obj:
            source.close()
    error = report["embedded_vs_true"]
    return {key: error.get(key) for key in FIGURES}


def rig_errors(rig, resolution, size, count):
    """Both ways of following on the rig and on its twin; for the subdivision rig also the
    surface bound to the subdivided mesh instead of the cage."""
    out = {}
    for full in (True, False):
        bpy.ops.wm.read_homefile(use_empty=True)
        obj, keywords = artist_rigs.build(rig, full)
        spec = evaluation_spec(PoseSpec(count=count, **keywords))
        chosen = deform.check_deformers(obj)
        part = {"chosen": chosen}
        for follow in (EVALUATED_SURFACE, ARMATURE_COPY, SURFACE_DEFORM):
            part[follow] = embedding(obj, spec, resolution, size, follow)
        if full and rig == "subdivision":
            kept = deform.SUBDIVIDING
            deform.SUBDIVIDING = ()
            try:
                part["evaluated surface (subdivided surface)"] = embedding(
                    obj, spec, resolution, size, EVALUATED_SURFACE)
            finally:
                deform.SUBDIVIDING = kept
        out["full rig" if full else "armature or lattice only"] = part
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, type=pathlib.Path)
    parser.add_argument("--poses", type=int, default=8, help="poses timed and evaluated")
    parser.add_argument("--resolution", type=int, default=32)
    parser.add_argument("--size", type=int, default=96, help="reference image side")
    args = parser.parse_args()
    check_output_file(args.json, "--json", "json")      # the output rule, before any scene
    cpu, _ = cpu_description()     # as every results JSON names it
    results = {"format": FORMAT, "command": " ".join(["python", *sys.argv]), "cpu": cpu,
               "cpus": os.cpu_count(), "blender": bpy.app.version_string,
               "note": "wall-clock medians on a machine shared with other sessions' work "
                       "(loaded): compare the figures side by side, not with other runs"}
    bpy.ops.wm.read_homefile(use_empty=True)
    arm = demo_scene("arm")
    results["cost_arm"] = pose_costs(arm, args.resolution, args.poses)
    results["cost_arm_subdivided"] = []
    for levels in (1, 2, 3):
        bpy.ops.wm.read_homefile(use_empty=True)
        arm = demo_scene("arm")
        arm.modifiers.new("Subdivision", "SUBSURF").levels = levels
        results["cost_arm_subdivided"].append(
            {"levels": levels, **pose_costs(arm, args.resolution, args.poses, cage_too=True)})
    results["embedding"] = {
        rig: rig_errors(rig, args.resolution, args.size, args.poses)
        for rig in artist_rigs.RIGS}
    results = stamp(results, with_machine=True)
    write_json_atomic(args.json, results, "--json", indent=1)
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, errors=VDNIFError, prefix="surface_corners_study: error: ")
