"""The procedural armature weights every vertex, so a pose moves every part of a mesh and
tears none. On the slab of ``tools/dev_meshes.py`` Blender's automatic weights (bone heat)
leave part of the mesh without any weight; the rig then weights the chain by place, and a
bent pose stretches no edge much, where the bone-heat weights alone tear it open."""

import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest

MESHES_TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "dev_meshes.py"


@pytest.fixture(scope="module")
def slab_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("slab")
    subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(folder), "--mesh", "slab"],
                   check=True, capture_output=True, timeout=300)
    return folder / "slab.obj"


def largest_stretch(obj):
    """The largest ratio of an edge's length in the current pose to its rest length."""
    import bpy

    rest = np.array([v.co[:] for v in obj.data.vertices])
    depsgraph = bpy.context.evaluated_depsgraph_get()
    posed = np.array([v.co[:] for v in obj.evaluated_get(depsgraph).data.vertices])
    edges = np.array([e.vertices[:] for e in obj.data.edges])
    length = lambda co: np.linalg.norm(co[edges[:, 0]] - co[edges[:, 1]], axis=1)  # noqa: E731
    return float((length(posed) / length(rest)).max())


def bend(obj, degrees):
    """Turns every bone of the object's armature by ``degrees`` about two axes."""
    armature = obj.find_armature()
    for k, bone in enumerate(armature.pose.bones):
        bone.rotation_mode = "XYZ"
        bone.rotation_euler = (math.radians(degrees), 0.0, math.radians(degrees) * (-1) ** k)


def test_every_vertex_is_weighted_and_a_bent_slab_does_not_tear(empty_scene, core, slab_file,
                                                                monkeypatch):
    import bpy

    scenes = core("blender.scenes")
    obj = scenes.mesh_scene(slab_file, rig="armature")
    weights = scenes.bone_weights(obj)
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-6)
    bend(obj, 45)
    stretch = largest_stretch(obj)
    assert stretch < 2.0

    # the same mesh with bone heat's weights alone: some vertices have none, and the same
    # pose tears the surface
    bpy.ops.wm.read_homefile(use_empty=True)
    monkeypatch.setattr(scenes, "_chain_weights", lambda *args: None)
    bare = scenes.mesh_scene(slab_file, rig="armature")
    assert (scenes.bone_weights(bare).sum(1) == 0).any()
    bend(bare, 45)
    assert largest_stretch(bare) > 3.0 > 1.5 * stretch
