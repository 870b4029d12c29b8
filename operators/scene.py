"""Voxelize (with its wireframe preview; optional, a look at the cells before training) and
Generate Dataset (in a worker, ``running``)."""

import json

import bpy

from .. import storage, viewer
from .common import VDNIFOperator
from .running import JobOperator, Stage, outcome


class VDNIF_OT_voxelize(VDNIFOperator, bpy.types.Operator):
    """Optional: show the occupied voxel cells, deformed at the current frame, as a wireframe
    (training voxelizes by itself)"""

    bl_idname = "vdnif.voxelize"
    bl_label = "Voxelize"
    bl_options = {"REGISTER", "UNDO"}
    needs = ("mesh", "torch", "idle")     # the corners' way is measured by rendering

    def work(self, context, obj):
        settings = obj.vdnif
        settings.preview, figures = viewer.voxel_preview(obj, settings.resolution,
                                                             settings.preview,
                                                             settings.pose_spec())
        settings.voxel_info = (f"grid {'x'.join(map(str, figures['dims']))}, "
                               f"{figures['cells']} occupied cells, "
                               f"{figures['inverted']} inverted at frame "
                               f"{context.scene.frame_current}; corners follow: "
                               f"{figures['corners_follow']}")
        return f"'{obj.name}': {settings.voxel_info}"


def suggestion_stage(name, kept=""):
    """Suggests the voxel resolution of object ``name`` for its pose settings
    (``ui_jobs.suggestion_job``) into its resolution field; ``kept``: what a cancel or
    failure leaves, said after its message."""

    def make():
        from ..vdnif_addon.blender.resolution import resolution_floor
        from ..vdnif_addon.blender.ui_jobs import suggestion_job
        from ..vdnif_addon.settings import RESOLUTION_CANDIDATES

        obj = bpy.data.objects[name]
        floor = resolution_floor(obj)          # reads the rest mesh: on the main thread
        return suggestion_job(obj, obj.vdnif.pose_spec(), None, floor, RESOLUTION_CANDIDATES)

    def finish(obj, state):
        outcome(state)
        if state.status != "completed":
            return f"'{obj.name}': {state.message}{kept}"
        settings, suggestion = obj.vdnif, state.result
        suggests = settings.resolution_auto       # a resolution set reads as the user's
        settings.resolution = suggestion.resolution
        settings.resolution_auto = suggests
        settings.resolution_info = f"suggested {suggestion.describe()}"
        return f"'{obj.name}': {settings.resolution_info}"

    return Stage(make, finish)


def suggested_first(obj, kept=""):
    """The suggestion's stage where the object's resolution is suggested (Suggest on), else
    nothing: what a run from scratch does before it captures."""
    return [suggestion_stage(obj.name, kept)] if obj.vdnif.resolution_auto else []


class VDNIF_OT_suggest_resolution(JobOperator, bpy.types.Operator):
    """Set the coarsest voxel resolution whose embedding error is close to the best candidate's,
    finer where parts are thin (measured on a few poses at each candidate). Esc cancels"""

    bl_idname = "vdnif.suggest_resolution"
    bl_label = "Suggest Resolution"
    needs = ("mesh", "idle")

    def stages(self, context, obj):
        return [suggestion_stage(obj.name)]


def dataset_settings(obj):
    """The settings a dataset is made with (recorded with it: Train regenerates a dataset
    made with other ones)."""
    settings = obj.vdnif
    variant, _ = settings.chosen_variant()
    return {"variant": variant, "resolution": settings.resolution,
            "pose_source": settings.pose_source, "poses": settings.pose_count,
            "seed": settings.seed, "max_angle": round(settings.max_angle, 6),
            "rays_per_pose": settings.rays_per_pose}


def follow_stage(name, made, kept=""):
    """Chooses how the corners of object ``name`` follow it in training with its settings
    (``ui_jobs.follow_job``, measured in a worker) into ``made["choice"]``; ``kept``: what
    a cancel or failure leaves, said after its message."""

    def choose():
        from ..vdnif_addon.blender.ui_jobs import follow_job

        settings = bpy.data.objects[name].vdnif
        return follow_job(bpy.data.objects[name], settings.resolution, settings.pose_spec())

    def chosen(obj, state):
        outcome(state)
        if state.status != "completed":
            return f"'{obj.name}': {state.message}{kept}"
        made["choice"] = state.result
        return f"'{obj.name}': {state.message}"

    return Stage(choose, chosen, undo=False)


def dataset_stages(context, obj, choice=None):
    """Generates the object's dataset (``ui_jobs.dataset_job``) after suggesting its
    resolution where it is suggested and choosing how its corners follow it
    (``follow_stage``; ``choice``: the FollowChoice measured already for these settings, by
    the estimate, which suggested the resolution before it): the poses are captured on the
    main thread, walked in the worker; a cancel keeps the previous dataset. What it records
    is what it was made with, whatever the settings became meanwhile."""
    name, made = obj.name, {"choice": choice}

    def make():
        from ..vdnif_addon.blender.capture_scene import capture
        from ..vdnif_addon.blender.ui_jobs import dataset_job

        obj = bpy.data.objects[name]
        settings = obj.vdnif
        made.update(settings=dataset_settings(obj), folder=storage.dataset_folder(obj))
        from ..vdnif_addon.safe_io import claim_folder

        claim_folder(made["folder"], "dataset folder")   # new, empty or VDNIF's: the rule
        captured = capture(obj, settings.resolution, settings.pose_spec(),
                           deform_corners=False, follow=made["choice"].follow)
        return dataset_job(obj, captured, made["settings"]["variant"], made["folder"],
                           settings.rays_per_pose, settings.seed)

    def finish(obj, state):
        outcome(state)
        if state.status != "completed":
            return f"'{obj.name}': {state.message}; the previous dataset is kept"
        settings, folder, recorded = obj.vdnif, made["folder"], made["settings"]
        settings.dataset_dir = storage.portable(folder)
        counts = state.result.counts
        from ..vdnif_addon.blender.ui_jobs import dataset_files

        size = sum(path.stat().st_size for path in dataset_files(folder))
        settings.dataset_info = json.dumps({
            "variant": recorded["variant"], "resolution": recorded["resolution"],
            "poses": len(state.result.poses), "rays": counts.rays,
            "segments": counts.segments, "hits": counts.hits, "bytes": size,
            "settings": recorded})
        choice = made["choice"]
        return (f"'{obj.name}': {counts.segments:,} segments of {counts.rays:,} rays, "
                f"{size / 1e6:.1f} MB -> {settings.dataset_dir}; corners follow: "
                f"{choice.follow}" + (f" (chosen in {choice.seconds:.1f} s)" if choice.errors
                                      else ""))

    # An estimate measured for these settings (``choice``) suggested the resolution already.
    kept = "; the previous dataset is kept"
    first = [] if choice is not None else [*suggested_first(obj, kept),
                                           follow_stage(name, made, kept)]
    return first + [Stage(make, finish)]


class VDNIF_OT_generate_dataset(JobOperator, bpy.types.Operator):
    """Walk training rays through the deformed voxels of every pose and write the dataset
    (Train does this by itself when the dataset is missing). Esc cancels"""

    bl_idname = "vdnif.generate_dataset"
    bl_label = "Generate Dataset"
    needs = ("mesh", "torch", "idle")

    def stages(self, context, obj):
        return dataset_stages(context, obj)


classes = (VDNIF_OT_voxelize, VDNIF_OT_suggest_resolution, VDNIF_OT_generate_dataset)
