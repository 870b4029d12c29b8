"""Writes ``object_settings.blend``: a mesh object 'Probe' whose panel settings
(``Object.vdnif``) are set away from their defaults, saved by the extension as it was before
the panel's properties were generated from the settings' declarations, so that
``tests/test_settings_blend.py`` can show a .blend saved then still finds every value under
the generated properties. Rerunning it with today's extension proves nothing: keep the file.
Run from the root of a checkout of that older extension, with the bpy module:

    python tests/golden/make_object_settings_blend.py
"""

import pathlib
import sys

GOLDEN = pathlib.Path(__file__).resolve().parent / "object_settings.blend"
REPO = pathlib.Path(__file__).resolve().parents[2]
VALUES = {"resolution": 48, "pose_source": "frames", "pose_count": 12, "seed": 7,
          "max_angle": 30.5, "rays_per_pose": 4096, "variant": "lsnif", "levels": 5,
          "base_resolution": 32, "log2_table_size": 12, "feature_dim": 4, "pe_bands": 0,
          "width": 48, "depth": 2, "steps": 1500, "batch_size": 4096, "device": "cuda",
          "precision": "bfloat16", "image_width": 200, "image_height": 150, "eval_poses": 3,
          "ao_samples": 32, "ao_distance": 0.25}
"""The saved values: each enum away from its first item (a .blend stores an enum's number)."""


def main():
    sys.path.insert(0, str(REPO / "tests"))
    from conftest import ENABLE_IN_FRESH_PROCESS

    exec(ENABLE_IN_FRESH_PROCESS)
    import bpy

    mesh = bpy.data.meshes.new("Probe")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("Probe", mesh)
    for name, value in VALUES.items():
        setattr(obj.vdnif, name, value)
    assert {name: getattr(obj.vdnif, name) for name in VALUES} == VALUES
    bpy.data.libraries.write(str(GOLDEN), {obj}, compress=True)
    print(f"wrote {GOLDEN}")


if __name__ == "__main__":
    main()
