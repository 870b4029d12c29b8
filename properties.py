"""Per-object settings (``Object.vdnif``), saved with the .blend, so each deforming object keeps
its own voxels, poses, dataset, network, model and last metrics; and the pass viewer's
choice (``Scene.vdnif_viewer``)."""

import json

import bpy
from bpy.props import (EnumProperty, FloatProperty, IntProperty, PointerProperty,
                       StringProperty)

from . import preferences, viewer
from .vdnif_addon import limits
from .vdnif_addon.settings import RECIPE

# Numbered: a .blend stores an enum by number, and "auto" came after the other three.
VARIANTS = [("auto", "Automatic", "LSNIF where no armature or lattice deforms the object "
                                  "(a static scene), else Proposed; each with its own PE "
                                  "bands", 3),
            ("proposed", "Proposed", "VDNIF: positional bands, log1p distance, "
                                     "uncertainty weighting, trained on many poses", 0),
            ("deformed", "Deformed", "The LSNIF model trained on many poses", 1),
            ("lsnif", "LSNIF", "The static baseline: hash grid only, trained on the rest "
                               "pose", 2)]
NETWORK_FIELDS = ("levels", "base_resolution", "log2_table_size", "feature_dim", "pe_bands",
                  "width", "depth")
TRAIN_FIELDS = ("steps", "batch_size")


def _variant_changed(settings, _context):
    """A variant brings its own positional bands (none for the hash-grid-only baselines)."""
    if preferences.torch_available() and settings.variant != "auto":
        from .vdnif_addon.variants import VARIANTS as DEFINITIONS

        settings.pe_bands = DEFINITIONS[settings.variant]["pe_bands"]


class VDNIFSettings(bpy.types.PropertyGroup):
    resolution: IntProperty(name="Voxel Resolution", default=RECIPE.resolution, min=4, max=256,
                            description="Voxels along the object's longest side")
    pose_source: EnumProperty(name="Poses", default="random", items=[
        ("random", "Random", "Random bone rotations and lattice offsets"),
        ("frames", "Frame Range", "Frames spread over the scene's frame range")])
    pose_count: IntProperty(name="Pose Count", default=RECIPE.poses, min=1,
                            max=limits.MAX_POSES, soft_max=1024)
    seed: IntProperty(name="Seed", default=0, min=0)
    max_angle: FloatProperty(name="Maximum Angle", default=45.0, min=0.1, max=180.0,
                             description="Largest random bone rotation per axis in degrees, "
                                         "for bones without rotation limits")
    rays_per_pose: IntProperty(name="Rays per Pose", default=RECIPE.rays_per_pose, min=1,
                               max=limits.MAX_RAYS_PER_POSE, soft_max=65536)
    variant: EnumProperty(name="Variant", items=VARIANTS, default="auto",
                          update=_variant_changed)
    levels: IntProperty(name="Levels", default=2, min=1, max=64, soft_max=16)
    base_resolution: IntProperty(name="Base Resolution", default=64, min=1, max=2**16)
    log2_table_size: IntProperty(name="Table Size (log2)", default=16, min=1,
                                  max=limits.MAX_LOG2_TABLE_SIZE)
    feature_dim: IntProperty(name="Feature Dim", default=3, min=1, max=64)
    pe_bands: IntProperty(name="PE Bands", default=3, min=0, max=16,
                          description="Positional-encoding bands (0: plain hash grid)")
    width: IntProperty(name="Width", default=64, min=1, max=4096)
    depth: IntProperty(name="Depth", default=3, min=1, max=64)
    steps: IntProperty(name="Steps", default=RECIPE.steps, min=1, max=10**7)
    batch_size: IntProperty(name="Batch Size", default=RECIPE.batch_size, min=1, max=2**24)
    device: EnumProperty(name="Device", default="PREFERENCES", items=[
        ("PREFERENCES", "Preferences", "The device chosen in the add-on's preferences"),
        *preferences.DEVICES])
    view: EnumProperty(name="View", default="CAMERA", items=[
        ("CAMERA", "Camera", "Render through the scene's active camera"),
        ("VIEWPORT", "Viewport", "Render the 3D Viewport's view")])
    image_width: IntProperty(name="Width", default=320, min=1, max=8192, subtype="PIXEL")
    image_height: IntProperty(name="Height", default=240, min=1, max=8192, subtype="PIXEL")
    eval_poses: IntProperty(name="Evaluation Poses", default=8, min=1, max=1000,
                            description="Unseen poses the model is evaluated on")
    dataset_dir: StringProperty(name="Dataset Folder", subtype="DIR_PATH",
                                options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                                description="Empty: beside the .blend (or in the user folder "
                                            "while the .blend is unsaved)")
    model_storage: EnumProperty(name="Model Storage", default="PACKED", items=[
        ("PACKED", "Packed", "Inside the .blend file"),
        ("FILE", "File", "A file beside the .blend (relative path)")],
        description="Where the next trained or loaded model is kept")
    model_path: StringProperty(name="Model File", subtype="FILE_PATH",
                               options={"HIDDEN", "PATH_SUPPORTS_BLEND_RELATIVE"})
    model_info: StringProperty(options={"HIDDEN"})       # JSON: storage.model_summary
    metrics: StringProperty(options={"HIDDEN"})          # JSON: the last evaluation report
    voxel_info: StringProperty(options={"HIDDEN"})
    resolution_info: StringProperty(options={"HIDDEN"})
    dataset_info: StringProperty(options={"HIDDEN"})     # JSON: what the dataset holds
    last_error: StringProperty(options={"HIDDEN"})
    preview: PointerProperty(type=bpy.types.Object, name="Voxel Preview")

    def pose_spec(self, count=None):
        from .vdnif_addon.blender.poses import PoseSpec

        return PoseSpec(source=self.pose_source, count=count or self.pose_count,
                        seed=self.seed, max_angle_deg=self.max_angle)

    def device_name(self, context):
        return preferences.device(context) if self.device == "PREFERENCES" else self.device

    def overrides(self, context):
        """The NetworkConfig / TrainConfig fields these settings choose (the automatic
        variant keeps its own PE bands)."""
        fields = {name: getattr(self, name) for name in NETWORK_FIELDS + TRAIN_FIELDS
                  if not (name == "pe_bands" and self.variant == "auto")}
        return dict(fields, seed=self.seed, device=self.device_name(context))

    def chosen_variant(self):
        """(variant, note) to generate data for and train: the chosen one, or for
        Automatic the static variant where no armature or lattice deforms the object
        (``variants.choose_variant``; the note says what was decided, or None)."""
        from .vdnif_addon.blender.read_mesh import deform_modifiers
        from .vdnif_addon.variants import choose_variant

        return choose_variant(None if self.variant == "auto" else self.variant,
                              not deform_modifiers(self.id_data))

    def adopt(self, metadata):
        """Takes the variant, resolution and network settings of a loaded model."""
        self.variant = metadata["extra"]["variant"]
        self.resolution = metadata["extra"]["grid"]["resolution"]
        network = metadata["network_config"]
        for name in NETWORK_FIELDS:
            setattr(self, name, getattr(network, name))

    def parsed(self, name):
        """The JSON property ``name`` as a dict (empty when unset)."""
        text = getattr(self, name)
        return json.loads(text) if text else {}


class VDNIFViewer(bpy.types.PropertyGroup):
    pass_name: EnumProperty(name="Pass", items=[(name, name.title(), "")
                                                for name in viewer.PASSES],
                            update=lambda choice, context: viewer.show(context, choice))
    source: EnumProperty(name="Show", items=[(name, name.title(), text) for name, text in (
        ("reference", "Blender's deformed mesh"), ("predicted", "The network"),
        ("error", "Error of the prediction against the reference"))],
        default="predicted",
        update=lambda choice, context: viewer.show(context, choice))


classes = (VDNIFSettings, VDNIFViewer)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.vdnif = PointerProperty(type=VDNIFSettings)
    bpy.types.Scene.vdnif_viewer = PointerProperty(type=VDNIFViewer)


def unregister():
    del bpy.types.Scene.vdnif_viewer
    del bpy.types.Object.vdnif
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
