"""Voxelize (with its wireframe preview) and Generate Dataset."""

import json

import bpy

from .. import storage, viewer
from .common import VDNIFOperator, progress


class VDNIF_OT_voxelize(VDNIFOperator, bpy.types.Operator):
    """Voxelize the mesh; show its occupied cells, deformed at the current frame, as a wireframe"""

    bl_idname = "vdnif.voxelize"
    bl_label = "Voxelize"
    bl_options = {"REGISTER", "UNDO"}
    needs = ("mesh", "idle")

    def work(self, context, obj):
        settings = obj.vdnif
        settings.preview, figures = viewer.voxel_preview(obj, settings.resolution,
                                                             settings.preview)
        settings.voxel_info = (f"grid {'x'.join(map(str, figures['dims']))}, "
                               f"{figures['cells']} occupied cells, "
                               f"{figures['inverted']} inverted at frame "
                               f"{context.scene.frame_current}")
        return f"'{obj.name}': {settings.voxel_info}"


class VDNIF_OT_suggest_resolution(VDNIFOperator, bpy.types.Operator):
    """Set the coarsest voxel resolution whose embedding error is small beside the network's"""

    bl_idname = "vdnif.suggest_resolution"
    bl_label = "Suggest Resolution"
    bl_options = {"REGISTER", "UNDO"}
    needs = ("mesh", "idle")

    def work(self, context, obj):
        from ..vdnif_addon.blender.resolution import network_error, suggest_resolution
        from ..vdnif_addon.settings import EMBEDDING_ERROR_SHARE

        settings = obj.vdnif
        target = EMBEDDING_ERROR_SHARE * network_error()
        settings.resolution, table = suggest_resolution(obj, settings.pose_spec(), target)
        tried = ", ".join(f"{row['resolution']}: {row['embedding_error']:.2g}"
                          for row in table)
        settings.resolution_info = (f"suggested {settings.resolution}: embedding error "
                                    f"{tried} (target {target:.2g} object units)")
        return f"'{obj.name}': {settings.resolution_info}"


class VDNIF_OT_generate_dataset(VDNIFOperator, bpy.types.Operator):
    """Walk training rays through the deformed voxels of every pose and write the dataset"""

    bl_idname = "vdnif.generate_dataset"
    bl_label = "Generate Dataset"
    needs = ("mesh", "torch", "idle")

    def work(self, context, obj):
        from ..vdnif_addon.blender.capture_scene import capture
        from ..vdnif_addon.blender.jobs import variant_dataset

        settings = obj.vdnif
        variant, _ = settings.chosen_variant()
        captured = capture(obj, settings.resolution, settings.pose_spec(),
                           deform_corners=False)
        folder = storage.dataset_folder(obj)
        storage.clear_dataset(folder)
        with progress(context, len(captured.poses)) as update:
            header = variant_dataset(obj, captured, variant, folder,
                                     settings.rays_per_pose, settings.seed, progress=update)
        settings.dataset_dir = storage.portable(folder)
        counts = header.counts
        settings.dataset_info = json.dumps({
            "variant": variant, "resolution": settings.resolution,
            "poses": len(header.poses), "rays": counts.rays,
            "segments": counts.segments, "hits": counts.hits})
        return (f"'{obj.name}': {counts.segments} segments of {counts.rays} rays "
                f"-> {settings.dataset_dir}")


classes = (VDNIF_OT_voxelize, VDNIF_OT_suggest_resolution, VDNIF_OT_generate_dataset)
