"""Per-object settings (``Object.vdnif``), saved with the .blend, so each deforming object keeps
its own voxels, poses, dataset, network, model and last metrics; and the pass viewer's
choice (``Scene.vdnif_viewer``)."""

import dataclasses
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
from .vdnif_addon import declarations as declared
from .vdnif_addon import settings as defaults
from .vdnif_addon.pose_sets import PoseSpec
from .vdnif_addon.presets import PRESET_VARIANT
from .vdnif_addon.presets import SETTINGS as PRESET_SETTINGS


def _variant_changed(settings: "VDNIFSettings", _context: bpy.types.Context) -> None:
    """A variant brings its own positional bands (none for the hash-grid-only baselines)."""
    if settings.variant != defaults.AUTO_VARIANT:
        settings.pe_bands = defaults.VARIANTS[settings.variant]["pe_bands"]


_UPDATES = {"variant": _variant_changed}
"""Panel properties that act when they change."""

SUGGESTED_BY_DEFAULT = (declared.RESOLUTION.option.default_for(declared.RESOLUTION, "train")
                        == declared.AUTO_RESOLUTION)
"""Whether a run from scratch suggests the resolution unless told: as ``train`` does."""
_SUGGEST_KEY = "resolution_auto_set"
"""Where Suggest's value is kept once set (an ID property of the object's settings)."""


def _suggests(settings: "VDNIFSettings") -> bool:
    """Suggest's value. An object whose resolution was set before the toggle was (by a .blend
    of an earlier version, where a resolution was always the user's) reads it as off, so that
    its resolution is never replaced."""
    stored = settings.get(_SUGGEST_KEY)
    if stored is not None:
        return bool(stored)
    return SUGGESTED_BY_DEFAULT and "resolution" not in settings.keys()


def _set_suggests(settings: "VDNIFSettings", value: bool) -> None:
    settings[_SUGGEST_KEY] = bool(value)


def declared_property(setting: declared.Setting, panel: declared.Panel) -> object:
    """The Blender property that ``panel`` declares for ``setting``: its type from the
    setting's, its hard range the setting's declared range, its items the setting's choices
    (``declarations``)."""
    words = {"name": panel.label, "description": panel.description,
             "default": panel.default_of(setting)}
    words.update((key, value) for key in ("soft_min", "soft_max", "subtype", "precision")
                 if (value := getattr(panel, key)) is not None)
    if panel.rna in _UPDATES:
        words["update"] = _UPDATES[panel.rna]
    if setting.choices:
        return EnumProperty(items=setting.enum_items(panel.extra), **words)
    if setting.kind is bool:
        return BoolProperty(**words)
    make = IntProperty if setting.kind is int else FloatProperty
    return make(min=setting.low, max=setting.high, **words)


DECLARED = {rna: declared_property(*pair) for rna, pair in declared.panel_properties().items()}
"""RNA name -> property of every setting the panel holds; the names are a .blend's keys."""
NETWORK_FIELDS, TRAIN_FIELDS = (
    tuple(name for name in DECLARED if name in {field.name for field in dataclasses.fields(kind)})
    for kind in (defaults.NetworkConfig, defaults.TrainConfig))
"""The NetworkConfig and TrainConfig fields the panel holds (``adopt`` takes the first from a
loaded model)."""


def _declared(cls: type) -> type:
    """Adds the declared settings' properties (``DECLARED``) to the property group ``cls``."""
    cls.__annotations__ = {**DECLARED, **cls.__annotations__}
    return cls


@_declared
class VDNIFSettings(bpy.types.PropertyGroup):
    # The settings the panel shares with the commands and the core are DECLARED; these are
    # the panel's own state.
    view: EnumProperty(name="View", default="CAMERA", items=[
        ("CAMERA", "Camera", "Render through the scene's active camera"),
        ("VIEWPORT", "Viewport", "Render the 3D Viewport's view")],
        description="What the passes are rendered through")
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
    pass_shaded: BoolProperty(
        name="Shaded", default=False,
        description="The albedo lit by the scene's first sun or point light and its world: "
                    "Render Passes, Render Animation and Evaluate cast the AO and shadow rays "
                    "it is made of and write the Shaded pass into each frame's EXR")
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
    resolution_auto: BoolProperty(
        name="Suggest", default=SUGGESTED_BY_DEFAULT, get=_suggests, set=_set_suggests,
        description="Train, Generate Dataset and Estimate suggest the voxel resolution first "
                    "(as the magnifier does) and train at it; off: the resolution set here")
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
        and its resolution (Suggest off) included."""
        self.variant = PRESET_VARIANT
        self.resolution_auto = False        # a preset was measured at its own resolution
        for name in PRESET_SETTINGS:
            setattr(self, name, preset[name])

    def adopt(self, metadata: object) -> None:
        """Takes the variant, resolution (Suggest off) and network settings of a loaded model
        (its ``ModelMetadata``)."""
        self.variant = metadata.variant
        self.resolution_auto = False        # training again keeps the model's resolution
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
                        "(rendered while its pass toggle is on)",
              "shaded": "The surface lit by the scene's first sun or point light and its "
                        "world, with the shadow and AO passes (rendered while its pass "
                        "toggle is on)"}


class VDNIFViewer(bpy.types.PropertyGroup):
    pass_name: EnumProperty(name="Pass", items=[
        (name, viewer.PASS_TITLES[name], _PASS_TEXT[name]) for name in viewer.SHOWN],
        description="The pass the Image Editor shows",
        update=viewer.choice_changed)
    source: EnumProperty(name="Show", items=[(name, name.title(), text) for name, text in (
        ("reference", "Blender's deformed mesh"), ("predicted", "The network"),
        ("error", "Error of the prediction against the reference"))],
        default="predicted", description="The reference, the network's prediction or its "
                                         "error, each kept in its own image",
        update=viewer.choice_changed)


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
