"""Per-object settings (``Object.vdnif``), saved with the .blend, so each deforming object keeps
its own voxels, poses, dataset, network, model and last metrics; and the pass viewer's
choice (``Scene.vdnif_viewer``)."""

import json

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from . import preferences, viewer
from .operators import live_preview
from .vdnif_addon import settings as defaults
from .vdnif_addon.pose_sets import PoseSpec
from .vdnif_addon.presets import PRESET_VARIANT
from .vdnif_addon.presets import SETTINGS as PRESET_SETTINGS
from .vdnif_addon.settings import BOUNDS, RECIPE

# Numbered: a .blend stores an enum by number, and "auto" came after the other three.
_VARIANT_TEXT = {
    defaults.AUTO_VARIANT: ("Automatic", "LSNIF where no armature or lattice deforms the "
                            "object (a static scene), else Proposed; each with its own PE "
                            "bands", 3),
    "proposed": ("Proposed", "VDNIF: positional bands, log-space distance, uncertainty "
                 "weighting, trained on many poses", 0),
    "deformed": ("Deformed", "The LSNIF model trained on many poses", 1),
    "lsnif": ("LSNIF", "The static baseline: hash grid only, trained on the rest pose", 2)}
VARIANTS = [(name, *_VARIANT_TEXT[name])
            for name in (defaults.AUTO_VARIANT, *reversed(defaults.TRAINABLE_VARIANTS))]
"""The variant enum's items: Automatic, then ``settings.TRAINABLE_VARIANTS``."""
_POSE_SOURCE_TEXT = {"random": ("Random", "Random bone rotations and lattice offsets"),
                     "frames": ("Frame Range", "Frames spread over the scene's frame range")}
NETWORK_FIELDS = ("levels", "base_resolution", "log2_table_size", "feature_dim", "pe_bands",
                  "width", "depth")
TRAIN_FIELDS = ("steps", "batch_size")
NETWORK = defaults.NetworkConfig()
"""The default network, whose fields are the panel's defaults."""


def _variant_changed(settings: "VDNIFSettings", _context: bpy.types.Context) -> None:
    """A variant brings its own positional bands (none for the hash-grid-only baselines)."""
    if settings.variant != defaults.AUTO_VARIANT:
        settings.pe_bands = defaults.VARIANTS[settings.variant]["pe_bands"]


def _int(name: str, setting: str, default: int, **options: object) -> IntProperty:
    """An IntProperty whose hard range is ``settings.BOUNDS[setting]``."""
    low, high = BOUNDS[setting]
    return IntProperty(name=name, default=default, min=low, max=high, **options)


class VDNIFSettings(bpy.types.PropertyGroup):
    resolution: _int("Voxel Resolution", "resolution", RECIPE.resolution,
                     description="Voxels along the object's longest side: more follow finer "
                                 "detail and bends, and make the dataset larger")
    pose_source: EnumProperty(name="Poses", default=PoseSpec.source, items=[
        (name, *_POSE_SOURCE_TEXT[name]) for name in defaults.POSE_SOURCES],
        description="Where the poses the network learns from come from")
    pose_count: _int("Pose Count", "poses", RECIPE.poses, soft_max=1024,
                     description="Poses the network learns from: more poses cover more of "
                                 "the rig's motion; each adds to the dataset and its time")
    seed: _int("Seed", "seed", PoseSpec.seed,
               description="Starting number of the random poses and of training's random "
                           "choices: another seed gives other poses")
    max_angle: FloatProperty(name="Maximum Angle", default=PoseSpec.max_angle_deg,
                             min=BOUNDS["max_angle"][0], max=BOUNDS["max_angle"][1],
                             description="Largest random bone rotation per axis in degrees, "
                                         "for bones without rotation limits")
    rays_per_pose: _int("Rays per Pose", "rays_per_pose", RECIPE.rays_per_pose,
                        soft_max=65536,
                        description="Rays shot at the object in each pose to make training "
                                    "examples: more rays, fewer holes, a larger dataset")
    variant: EnumProperty(name="Variant", items=VARIANTS, default=defaults.AUTO_VARIANT,
                          update=_variant_changed,
                          description="Which kind of network to train")
    levels: _int("Levels", "levels", NETWORK.levels, soft_max=16,
                 description="Detail levels of the hash grid, coarse to fine: more levels "
                             "hold finer detail and render a little slower")
    base_resolution: _int("Base Resolution", "base_resolution", NETWORK.base_resolution,
                          description="Cells along each side of the coarsest hash-grid level")
    log2_table_size: _int("Table Size (log2)", "log2_table_size", NETWORK.log2_table_size,
                          description="Entries of each hash-grid level as a power of two (16: "
                                      "65,536): larger tables keep more detail in a larger "
                                      "model")
    feature_dim: _int("Feature Dim", "feature_dim", NETWORK.feature_dim,
                      description="Numbers stored per hash-grid entry: more hold more detail "
                                  "in a larger, slower model")
    pe_bands: _int("PE Bands", "pe_bands", NETWORK.pe_bands,
                   description="Positional-encoding bands: waves of rising frequency that let "
                               "the network place fine detail (0: none; Automatic uses its "
                               "variant's own)")
    width: _int("Width", "width", NETWORK.width,
                description="Neurons per layer of the network: wider learns more and renders "
                            "slower")
    depth: _int("Depth", "depth", NETWORK.depth,
                description="Hidden layers of the network: deeper learns more and renders "
                            "slower")
    steps: _int("Steps", "steps", RECIPE.steps,
                description="Training steps: more steps take longer and usually lower the "
                            "error")
    batch_size: _int("Batch Size", "batch_size", RECIPE.batch_size,
                     description="Ray pieces the network learns from per step: larger batches "
                                 "learn steadier and need more memory")
    device: EnumProperty(name="Device", default="PREFERENCES", items=[
        ("PREFERENCES", "Preferences", "The device chosen in the add-on's preferences"),
        *preferences.DEVICES],
        description="Where training and rendering run: the CPU or an NVIDIA GPU")
    precision: EnumProperty(name="Precision", default=defaults.DEFAULT_PRECISION, items=[
        ("float32", "Float32", "Full precision"),
        ("bfloat16", "BFloat16", "Faster where the device has bfloat16 instructions (an NVIDIA "
                                 "GPU, a CPU with AVX-512 BF16 or AMX), a little less exact")],
        description="The arithmetic of the network's layers when it renders")
    view: EnumProperty(name="View", default="CAMERA", items=[
        ("CAMERA", "Camera", "Render through the scene's active camera"),
        ("VIEWPORT", "Viewport", "Render the 3D Viewport's view")],
        description="What the passes are rendered through")
    image_width: _int("Width", "image_side", defaults.PANEL_IMAGE[0], subtype="PIXEL",
                      description="Width of the rendered pass images in pixels")
    image_height: _int("Height", "image_side", defaults.PANEL_IMAGE[1], subtype="PIXEL",
                       description="Height of the rendered pass images in pixels")
    eval_poses: _int("Evaluation Poses", "poses", defaults.EVALUATION_POSES,
                     description="Unseen poses the model is evaluated on")
    use_scene_size: BoolProperty(
        name="Scene Output Size", default=True,
        description="Render Passes, Render Animation, Evaluate and the live preview use the "
                    "scene's output resolution and percentage; off: the width and height below")
    pass_ao: BoolProperty(
        name="AO", default=False,
        description="Ambient occlusion: Render Passes, Render Animation and Evaluate cast AO "
                    "rays too (slower) and write the AO pass into each frame's EXR")
    pass_shadow: BoolProperty(
        name="Shadow", default=False,
        description="Shadow towards the scene's first sun or point light: Render Passes, Render "
                    "Animation and Evaluate cast shadow rays too and write the Shadow pass into "
                    "each frame's EXR")
    ao_samples: _int("AO Samples", "ao_samples", defaults.AO_SAMPLES, soft_max=256,
                     description="Ambient-occlusion rays per pixel: more give a smoother "
                                 "image and take longer")
    ao_distance: FloatProperty(name="AO Distance", default=defaults.AO_DISTANCE,
                               min=BOUNDS["ao_distance"][0], max=BOUNDS["ao_distance"][1],
                               soft_max=1.0, precision=3,
                               description="How far an ambient-occlusion ray looks for an "
                                           "occluder, in object units (the object's longest "
                                           "side is 1)")
    dataset_dir: StringProperty(name="Dataset Folder", subtype="DIR_PATH",
                                options={"PATH_SUPPORTS_BLEND_RELATIVE"},
                                description="Where the training examples are written. Empty: "
                                            "beside the .blend (or in the user folder while "
                                            "the .blend is unsaved)")
    model_storage: EnumProperty(name="Model Storage", default="PACKED", items=[
        ("PACKED", "Packed", "Inside the .blend file"),
        ("FILE", "File", "A file beside the .blend (relative path)")],
        description="Where the next trained or loaded model is kept")
    model_path: StringProperty(name="Model File", subtype="FILE_PATH",
                               options={"HIDDEN", "PATH_SUPPORTS_BLEND_RELATIVE"},
                               description="The model file, when it is kept beside the .blend")
    # What the panel shows, kept with the .blend (JSON where it says so).
    model_info: StringProperty(options={"HIDDEN"}, description="The trained model's summary "
                               "(storage.model_summary, JSON)")
    metrics: StringProperty(options={"HIDDEN"},
                            description="The last evaluation's report (JSON)")
    voxel_info: StringProperty(options={"HIDDEN"}, description="What Voxelize found")
    resolution_info: StringProperty(options={"HIDDEN"},
                                    description="Why the suggested resolution was chosen")
    dataset_info: StringProperty(options={"HIDDEN"},
                                 description="What the dataset holds (JSON)")
    estimate_info: StringProperty(options={"HIDDEN"}, description="The measured disk and "
                                  "time estimate and the settings it was measured for (JSON)")
    keep_partial_model: BoolProperty(
        name="Keep Partial Model on Cancel", default=False,
        description="Off: a cancelled training keeps the previous model (the first model is "
                    "kept even when cancelled). On: it keeps what the cancelled run learned")
    use_scene_frames: BoolProperty(
        name="Scene Frame Range", default=True,
        description="Render Animation renders the scene's frame range; off: the range below")
    frame_start: IntProperty(name="Start", default=1, description="First frame to render")
    frame_end: IntProperty(name="End", default=250, description="Last frame to render")
    frame_step: IntProperty(name="Step", default=1, min=1,
                            description="Render every this many frames")
    frames_dir: StringProperty(
        name="Output Folder", subtype="DIR_PATH", options={"PATH_SUPPORTS_BLEND_RELATIVE"},
        description="Where Render Animation writes its image sequences (empty: the scene's "
                    "output path)")
    live_preview: BoolProperty(
        name="Live Preview", default=False,
        update=lambda settings, context: live_preview.toggled(settings, context),
        description="Render the predicted passes at the preview size into the images "
                    "'VDNIF Preview <Pass>' whenever the frame changes (frames are skipped "
                    "rather than queued while one renders)")
    preview_percent: IntProperty(name="Preview Size", default=25, min=5, max=100,
                                 subtype="PERCENTAGE",
                                 description="The live preview's size, in percent of the "
                                             "render size")
    last_error: StringProperty(options={"HIDDEN"},
                               description="Why the last button failed")
    preview: PointerProperty(type=bpy.types.Object, name="Voxel Preview",
                             description="The wireframe object that shows the voxels")

    def pose_spec(self, count: int | None = None) -> PoseSpec:
        """The poses these settings choose (``count`` of them, default ``pose_count``)."""
        return PoseSpec(source=self.pose_source, count=count or self.pose_count,
                                 seed=self.seed, max_angle_deg=self.max_angle)

    def device_name(self, context: bpy.types.Context) -> str:
        """The device to run on: this object's choice or the preferences' one."""
        return preferences.device(context) if self.device == "PREFERENCES" else self.device

    def overrides(self, context: bpy.types.Context) -> dict[str, object]:
        """The NetworkConfig / TrainConfig fields these settings choose (the automatic
        variant keeps its own PE bands)."""
        fields = {name: getattr(self, name) for name in NETWORK_FIELDS + TRAIN_FIELDS
                  if not (name == "pe_bands" and self.variant == defaults.AUTO_VARIANT)}
        return dict(fields, seed=self.seed, device=self.device_name(context))

    def chosen_variant(self) -> tuple[str, str | None]:
        """(variant, note) to generate data for and train: the chosen one, or for
        Automatic the static variant where no armature or lattice deforms the object
        (``variants.choose_variant``; the note says what was decided, or None)."""
        from .vdnif_addon.blender.read_mesh import deform_modifiers
        from .vdnif_addon.model.variants import choose_variant

        return choose_variant(None if self.variant == defaults.AUTO_VARIANT else self.variant,
                              not deform_modifiers(self.id_data))

    def apply_preset(self, preset: dict[str, object]) -> None:
        """Takes every setting of a preset (an entry of ``presets.load_presets``), whole: the
        variant it was measured with first, then its own settings, the positional bands
        included."""
        self.variant = PRESET_VARIANT
        for name in PRESET_SETTINGS:
            setattr(self, name, preset[name])

    def adopt(self, metadata: object) -> None:
        """Takes the variant, resolution and network settings of a loaded model (its
        ``ModelMetadata``)."""
        self.variant = metadata.variant
        self.resolution = metadata.grid.resolution
        network = metadata.network_config
        for name in NETWORK_FIELDS:
            setattr(self, name, getattr(network, name))

    def parsed(self, name: str) -> dict[str, object]:
        """The JSON property ``name`` as a dict (empty when unset)."""
        text = getattr(self, name)
        return json.loads(text) if text else {}


_PASS_TEXT = {"normal": "Which way the surface faces (normal)",
              "albedo": "The surface's colour without lighting (diffuse colour)",
              "distance": "How far the surface is along the ray (depth)",
              "material": "The material slot of the surface (material index)",
              "ao": "Ambient occlusion: the share of rays from the surface that meet nothing "
                    "within the AO distance (rendered while its pass toggle is on)",
              "shadow": "Whether the scene's first sun or point light reaches the surface "
                        "(rendered while its pass toggle is on)"}


class VDNIFViewer(bpy.types.PropertyGroup):
    pass_name: EnumProperty(name="Pass", items=[
        (name, viewer.PASS_TITLES[name], _PASS_TEXT[name]) for name in viewer.SHOWN],
        description="The pass the Image Editor shows",
        update=lambda choice, context: viewer.show(context, choice))
    source: EnumProperty(name="Show", items=[(name, name.title(), text) for name, text in (
        ("reference", "Blender's deformed mesh"), ("predicted", "The network"),
        ("error", "Error of the prediction against the reference"))],
        default="predicted", description="The reference, the network's prediction or its "
                                         "error, each kept in its own image",
        update=lambda choice, context: viewer.show(context, choice))


classes = (VDNIFSettings, VDNIFViewer)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.vdnif = PointerProperty(type=VDNIFSettings)
    bpy.types.Scene.vdnif_viewer = PointerProperty(type=VDNIFViewer)


def unregister() -> None:
    del bpy.types.Scene.vdnif_viewer
    del bpy.types.Object.vdnif
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
