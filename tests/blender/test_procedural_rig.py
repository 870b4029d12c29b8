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
from obj_files import write_bars

MESHES_TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "dev_meshes.py"


def dev_mesh(tmp_path_factory, name):
    """The development mesh ``name`` of ``tools/dev_meshes.py``, built into a fresh folder."""
    folder = tmp_path_factory.mktemp(name)
    subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(folder), "--mesh", name],
                   check=True, capture_output=True, timeout=300)
    return folder / f"{name}.obj"


@pytest.fixture(scope="module")
def slab_file(tmp_path_factory):
    return dev_mesh(tmp_path_factory, "slab")


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


@pytest.fixture(scope="module")
def text_file(tmp_path_factory):
    return dev_mesh(tmp_path_factory, "text")


def inverted_cells(core, obj, resolution=96, poses=2):
    """The voxel cells each of ``poses`` development poses of ``obj`` inverts."""
    spec = core("blender.poses").evaluation_spec(core("pose_sets").PoseSpec(count=poses),
                                                 pose_set="development")
    return core("blender.capture_scene").capture(obj, resolution, spec).inverted_cells


def test_weights_that_jump_between_near_vertices_give_way_to_the_chains(empty_scene, core,
                                                                       text_file, monkeypatch):
    """The text of ``tools/dev_meshes.py``: bone heat weights every vertex, but vertices
    closer than a voxel at 96 a bone apart, and the voxels between them invert in a bend; the
    rig weights it by place along the chain instead, and they do not."""
    import bpy

    scenes = core("blender.scenes")
    obj = scenes.mesh_scene(text_file, rig="armature")
    weights = scenes.bone_weights(obj)
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-6)
    assert scenes.weight_jump(obj) < 0.1
    chained = inverted_cells(core, obj)

    bpy.ops.wm.read_homefile(use_empty=True)
    monkeypatch.setattr(scenes, "WEIGHT_JUMP", math.inf)
    bare = scenes.mesh_scene(text_file, rig="armature")
    assert (scenes.bone_weights(bare).sum(1) > 0).all()      # nothing torn: every vertex
    assert scenes.weight_jump(bare) > 2 * 0.5
    heat = inverted_cells(core, bare)
    assert heat.min() > 50 and chained.max() <= heat.min() / 10, (chained, heat)


def test_the_weight_jump_is_the_largest_between_vertices_within_reach(empty_scene, core):
    """``weight_jump`` against every pair of vertices, on points with weights of their own:
    pairs farther apart than the reach do not count, however different."""
    import bpy

    scenes = core("blender.scenes")
    rng = np.random.default_rng(3)
    co = rng.uniform(0, 1, (300, 3)) * [4.0, 1.0, 1.0]
    mesh = bpy.data.meshes.new("points")
    mesh.from_pydata(co.tolist(), [], [])
    obj = bpy.data.objects.new("points", mesh)
    bpy.context.scene.collection.objects.link(obj)
    weights = rng.uniform(0, 1, (300, 3)) * (rng.uniform(size=(300, 3)) < 0.7)
    weights[weights.sum(1) == 0, 0] = 1.0
    for bone in range(3):
        group = obj.vertex_groups.new(name=f"Bone.{bone}")
        for vertex in range(300):
            if weights[vertex, bone] > 0:
                group.add([vertex], float(weights[vertex, bone]), "REPLACE")
    normalized = weights / weights.sum(1, keepdims=True)
    reach = scenes.JUMP_REACH * np.ptp(co, axis=0).max()
    distance = np.linalg.norm(co[:, None] - co[None], axis=2)
    difference = np.abs(normalized[:, None] - normalized[None]).sum(2)
    expected = difference[distance <= reach].max()
    assert (distance <= reach).sum() > 300                    # some pairs besides the diagonal
    assert scenes.weight_jump(obj) == pytest.approx(expected, rel=1e-6)
    assert difference[distance > reach].max() > expected      # a far pair would say more


def rigged(core, mesh, rig="armature", riders_follow=True):
    """The mesh file ``mesh`` imported into an emptied file with the procedural ``rig``."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    obj = core("blender.mesh_files").import_mesh(str(mesh))
    return core("blender.scenes").add_rig(obj, rig, riders_follow=riders_follow)


def test_a_small_piece_that_touches_the_body_rides_on_it(empty_scene, core, tmp_path):
    """A separate piece weighted by bone heat on its own slides on the surface it sits on in
    a bend (Suzanne's eyes in their sockets); the rig gives a small touching piece the
    weights of the body's nearest vertex (also one seated on the body's vertices, 0 away), and
    leaves a far piece and a large one alone."""

    scenes = core("blender.scenes")
    mesh = tmp_path / "pieces.obj"
    body = ((0, 0, 0), (6, 1, 1), 12)
    touching = ((1.3, 1.0, 0.3), (1.7, 1.4, 0.7), 1)     # on the body's side, a tenth its size
    far = ((4.3, 3.0, 0.3), (4.7, 3.4, 0.7), 1)          # as small, 2 units away
    limb = ((0.5, -4.0, 0.2), (1.0, 0.0, 0.8), 4)        # touching, but 0.7 of the body's size
    seated = ((2.0, 1.0, 0.0), (2.5, 1.4, 1.0), 1)       # its base on body vertices: 0 away
    write_bars(mesh, [body, touching, far, limb, seated])
    rings = lambda piece: 4 * (piece[2] + 1)  # noqa: E731
    first = np.cumsum([0] + [rings(p) for p in (body, touching, far, limb, seated)])
    body_v, touching_v, far_v, limb_v, seated_v = (np.arange(first[k], first[k + 1])
                                                   for k in range(5))

    raw = scenes.bone_weights(rigged(core, mesh, riders_follow=False))   # bone heat's
    obj = scenes.mesh_scene(mesh, rig="armature")
    weights = scenes.bone_weights(obj)
    vertices = np.array([v.co[:] for v in obj.data.vertices])

    def nearest_body(members):
        """The body's nearest vertex to each of ``members``, by brute force."""
        gaps = np.linalg.norm(vertices[members, None] - vertices[None, body_v], axis=2)
        return body_v[gaps.argmin(1)]

    riding, sources = core("blender.pieces").riders(obj)
    assert sorted(riding) == [*touching_v, *seated_v]
    assert (sources == nearest_body(riding)).all()
    np.testing.assert_allclose(weights[riding], weights[sources])
    for kept in (body_v, far_v, limb_v):
        np.testing.assert_allclose(weights[kept], raw[kept])
    normalized = raw / raw.sum(1, keepdims=True)
    assert np.abs(normalized[touching_v] - normalized[nearest_body(touching_v)]).sum(1).max() > 0.1

    # Blender's own evaluation: bent, the riding piece keeps its place on the body, where
    # with bone heat's weights alone it slides
    def slide(scene_obj):
        import bpy

        rest = np.array([v.co[:] for v in scene_obj.data.vertices])
        bend(scene_obj, 45)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        posed = np.array([v.co[:] for v in scene_obj.evaluated_get(depsgraph).data.vertices])
        nearest = nearest_body(touching_v)
        before = np.linalg.norm(rest[touching_v] - rest[nearest], axis=1)
        after = np.linalg.norm(posed[touching_v] - posed[nearest], axis=1)
        return float(np.abs(after - before).max())

    riding_slide = slide(obj)
    alone_slide = slide(rigged(core, mesh, riders_follow=False))
    # riding, the gaps (0.36-0.6 at rest) change only by the blend of the bones' turns
    assert riding_slide < 0.1 < 0.5 < alone_slide


def test_a_piece_that_slides_is_named_where_the_corners_are_chosen(empty_scene, core,
                                                                   tmp_path):
    """An armature that moves a riding piece otherwise than the surface it touches (here
    bone heat's weights alone) cannot be followed by one voxel: the corners' choice names
    the piece, with its place and how far its weights differ; the procedural armature's own
    weighting, and a lattice, give nothing to name."""

    pieces, scenes = core("blender.pieces"), core("blender.scenes")
    steps, spec = core("blender.steps"), core("pose_sets").PoseSpec(count=2)
    mesh = tmp_path / "pieces.obj"
    write_bars(mesh, [((0, 0, 0), (6, 1, 1), 12), ((1.3, 1.0, 0.3), (1.7, 1.4, 0.7), 1)])
    body_v, box_v = np.arange(52), np.arange(52, 60)

    obj = rigged(core, mesh, riders_follow=False)
    vertices = np.array([v.co[:] for v in obj.data.vertices])
    raw = scenes.bone_weights(obj)
    weights = raw / raw.sum(1, keepdims=True)
    np.testing.assert_allclose(pieces.armature_weights(obj), weights)
    gaps = np.linalg.norm(vertices[box_v, None] - vertices[None, body_v], axis=2)
    expected = np.abs(weights[box_v] - weights[body_v[gaps.argmin(1)]]).sum(1).max()
    assert expected > pieces.SLIDE_DIFFERENCE      # bone heat weights the box by itself
    (count, centre, difference), = pieces.sliding(obj)
    assert count == 8 and difference == pytest.approx(expected)
    np.testing.assert_allclose(centre, vertices[box_v].mean(0), atol=1e-6)
    said = []
    steps.training_follow(obj, 16, spec, say=said.append)
    assert len(said) == 1 and "1 separate piece at (" in said[0]
    assert "moves otherwise than the surface it touches" in said[0]

    for rig in ("armature", "lattice"):
        quiet = rigged(core, mesh, rig)
        assert pieces.sliding(quiet) == ()
        said = []
        steps.training_follow(quiet, 16, spec, say=said.append)
        assert not any("separate piece" in line for line in said)
