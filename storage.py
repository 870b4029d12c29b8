"""Where an object's dataset and model live. The model goes with the .blend: packed into it
(its bytes in the object's settings) or as a file beside it (a ``//`` relative path); either
way reopening the .blend finds it. Packed models are unpacked on first use into a cache in
the extension's user folder, named by their SHA-256."""

import hashlib
import json
import os
import pathlib
import shutil

import bpy

from .vdnif_addon.errors import VDNIFError
from .vdnif_addon.safe_io import atomic_path, file_stem, write_bytes_atomic

PACKED = "model_data"     # the ID property of an object's settings holding the packed model


def user_folder(*parts):
    return pathlib.Path(bpy.utils.extension_path_user(__package__, path=os.path.join(*parts),
                                                      create=True))


def portable(path):
    """``path`` relative to the .blend (``//...``) when the .blend is saved, else absolute."""
    return bpy.path.relpath(str(path)) if bpy.data.filepath else str(path)


def slug(obj):
    """The object's name as a file name."""
    return file_stem(obj.name)


def _beside_blend(obj, name):
    return pathlib.Path(bpy.path.abspath(f"//vdnif/{slug(obj)}{name}"))


def _chosen_folder(obj, chosen, suffix, kind):
    """The folder ``chosen`` in the object's settings, else beside the .blend (named with
    ``suffix``), else (unsaved .blend) the user folder's ``kind``."""
    if chosen:
        return pathlib.Path(bpy.path.abspath(chosen))
    if bpy.data.filepath:
        return _beside_blend(obj, suffix)
    return user_folder(kind, slug(obj))


def dataset_folder(obj):
    """The object's dataset folder: its setting, else beside the .blend, else (unsaved
    .blend) in the user folder."""
    return _chosen_folder(obj, obj.vdnif.dataset_dir, "-dataset", "datasets")


def frames_output(obj, scene):
    """(folder, name prefix) where Render Animation writes the object's image sequences: its
    Output Folder setting; else the scene's output path as Blender reads it (a path ending
    in a separator is a folder, otherwise its last part starts every file name, as in
    ``//render/shot_``; relative to the user folder while the .blend is unsaved); else (no
    output path) beside the .blend, else (unsaved .blend) in the user folder."""
    if obj.vdnif.frames_dir or not scene.render.filepath:
        return _chosen_folder(obj, obj.vdnif.frames_dir, "-frames", "frames"), ""
    path = scene.render.filepath
    if path.startswith("//") and not bpy.data.filepath:     # relative to an unsaved .blend
        path = str(user_folder("frames", slug(obj))) + "/" + path[2:]
    path = bpy.path.abspath(path)
    if path.endswith(("/", "\\")) or pathlib.Path(path).is_dir():
        return pathlib.Path(path), ""
    path = pathlib.Path(path)
    return path.parent, path.name


def passes_folder(obj):
    """Where Render Passes writes the object's previews and multilayer EXRs: beside the
    .blend, else (unsaved .blend) in the user folder."""
    return _chosen_folder(obj, "", "-passes", "passes")


def images_folder(obj):
    """Where the pass viewer's and the loss plot's images of the object are saved, to be read
    back when the .blend is opened: beside the .blend, else (unsaved .blend) in the user
    folder."""
    return _chosen_folder(obj, "", "-images", "images")


def has_dataset(obj):
    folder = dataset_folder(obj)
    return folder.is_dir() and any(folder.glob("shard-*.json"))


def training_target(obj):
    """The file training writes the object's next model to: beside the .blend for file
    storage; for packed storage a work file in the user folder, packed when done."""
    if obj.vdnif.model_storage == "FILE":
        if not bpy.data.filepath:
            raise VDNIFError(f"'{obj.name}': save the .blend first so its model can be stored "
                             "beside it, or choose packed model storage")
        return _beside_blend(obj, ".vdnif")
    return user_folder("models") / f"{slug(obj)}-training.vdnif"


def keep_model(obj, path, summary):
    """Makes the model file ``path`` the object's model, packed or copied beside the .blend
    as its storage setting says, with ``summary`` (see ``model_summary``) for the panel."""
    settings = obj.vdnif
    path = pathlib.Path(path)
    packed = settings.model_storage == "PACKED"
    target = None if packed else training_target(obj)     # raises before anything changes
    if PACKED in settings:
        del settings[PACKED]        # assigning over it would store the bytes up to a NUL
    if packed:
        data = path.read_bytes()
        settings[PACKED] = data
        settings.model_path = ""
        cached = _cache_path(data)
        if path.parent == user_folder("models"):
            os.replace(path, cached)
        elif not cached.exists():
            _write_atomically(cached, data)
    else:
        if path.resolve() != target.resolve():
            _copy_atomically(path, target)
        settings.model_path = portable(target)
    settings.model_info = json.dumps(summary)


def model_path(obj):
    """The object's model as a file to load; raises a VDNIFError naming what is missing."""
    settings = obj.vdnif
    if PACKED in settings:
        data = bytes(settings[PACKED])
        cached = _cache_path(data)
        if not cached.exists():
            _write_atomically(cached, data)
        return cached
    if not settings.model_path:
        raise VDNIFError(f"'{obj.name}' has no trained model: generate a dataset and train, "
                         "or load a model file")
    path = pathlib.Path(os.path.normpath(bpy.path.abspath(settings.model_path)))
    if not path.is_file():
        raise VDNIFError(f"the model file of '{obj.name}', {settings.model_path}, is missing")
    return path


def has_model(obj):
    settings = obj.vdnif
    return PACKED in settings or (
        bool(settings.model_path) and os.path.isfile(bpy.path.abspath(settings.model_path)))


LOADED_FROM = "loaded_from"
"""The model summary's key naming the file a loaded model came from (Load Model): training
then replaces a model the user chose, and asks first."""


def loaded_model(obj):
    """The file the object's model was loaded from (Load Model), or None when it has no
    model or trained its own."""
    if not has_model(obj):
        return None
    return obj.vdnif.parsed("model_info").get(LOADED_FROM)


def model_location(obj):
    """Where the object's model is, in words, for the panel."""
    settings = obj.vdnif
    if PACKED in settings:
        return f"packed in the .blend ({len(settings[PACKED]) / 1e6:.2f} MB)"
    return settings.model_path or "none"


def export_model(obj, target):
    """Copies the object's model to the file ``target``, atomically."""
    _copy_atomically(model_path(obj), pathlib.Path(target))


def model_summary(metadata, path):
    """What the panel shows of a model file, from ``model_file.load_model``'s metadata."""
    training = metadata.training
    return {"object": metadata.object, "variant": metadata.variant,
            "resolution": metadata.grid.resolution, "status": training.status,
            "steps": training.steps, "seconds": training.seconds,
            "validation": None if training.validation is None else dict(training.validation),
            "corners_follow": metadata.corners_follow, "bytes": os.path.getsize(path)}


def _cache_path(data):
    return user_folder("models") / f"{hashlib.sha256(data).hexdigest()}.vdnif"


def _copy_atomically(source, target):
    # safe_io: fresh, exclusive, and only over a model VDNIF wrote
    with atomic_path(target, "model file", kind="model") as temporary:
        shutil.copyfile(source, temporary)


def _write_atomically(path, data):
    write_bytes_atomic(path, data, "model file", "model")
