"""The side-by-side study's scenes: their names, apart from its timing code so that the batch
parser can list them without importing torch or Warp (most of a failing command's start-up),
and how each is built (bpy, imported where used)."""

import pathlib

from ..errors import VDNIFError

SUZANNE_LEVELS = (2, 3, 4, 5, 6)  # Suzanne (968 triangles) subdivided: 15,744 .. 3,964,928
MILLION_LEVEL = 5                 # 'million': the 1 M-triangle scene, 1,007,616 triangles
SCENES = ("bunny", *(f"suzanne-{level}" for level in SUZANNE_LEVELS), "million", "arm",
          "lattice", "spot")


def scene_name(name):
    """The scene a name in ``SCENES`` stands for ('million' is suzanne-5)."""
    if name not in SCENES:
        raise VDNIFError(f"unknown scene '{name}': choose one of {', '.join(SCENES)}")
    return f"suzanne-{MILLION_LEVEL}" if name == "million" else name


def suzanne_scene(level):
    """Blender's Suzanne subdivided ``level`` times (Subdivision applied, flat faces) with the
    procedural lattice rig, in an emptied file: the scenes of the triangle-count sweep."""
    import bpy

    from ..blender.scenes import add_rig

    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_monkey_add()
    obj = bpy.context.active_object
    obj.name = f"Suzanne subdivided {level}"
    subdivision = obj.modifiers.new("Subdivision", "SUBSURF")
    subdivision.levels = level
    bpy.ops.object.modifier_apply(modifier=subdivision.name)
    return add_rig(obj, "lattice")


def load_side_by_side_scene(name):
    """The mesh object of a scene name in ``SCENES``, built in an emptied file."""
    from ..blender.scenes import demo_scene

    name = scene_name(name)
    if name.startswith("suzanne-"):
        return suzanne_scene(int(name.split("-")[1]))
    return demo_scene(name)


def save_blends(scenes, folder):
    """Saves each scene as ``folder/<scene>.blend`` for ``train --blend`` and says how."""
    import bpy

    from ..safe_io import atomic_path

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name in scenes:
        obj = load_side_by_side_scene(name)
        path = folder / f"{name}.blend"
        with atomic_path(path, ".blend file") as temporary:    # copy: the session keeps its file
            bpy.ops.wm.save_as_mainfile(filepath=str(pathlib.Path(temporary).resolve()),
                                        check_existing=False, copy=True)
            pathlib.Path(temporary + "1").unlink(missing_ok=True)  # Blender's backup of it
        print(f"saved scene '{name}' ('{obj.name}') to {path}: train with "
              f"train --blend {path} --object '{obj.name}'")
    return 0
