"""The bounds cases that run inside Blender with the extension: memory and disk refused
against what is free, a frame range counted before it is built, an array's offset object
read only when the array reads it, camera shift and clip range against Blender's own
projection, the framing rule, an evaluation that compared nothing, and the texture
fingerprint (``tests/cli/test_bad_inputs_bounds.py`` holds the batch catalogue)."""

import dataclasses
import datetime

import numpy as np
import pytest
from bounds_blends import build
from camera_pixels import assert_rays_hit_their_pixels
from model_metadata import capture_metadata
from oracle_network import oracle_scene_model


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return build(tmp_path_factory.mktemp("blends"))


def test_memory_and_disk_refusals_compare_with_what_is_free(tmp_path, monkeypatch, core):
    memory = core("memory")
    errors = core("errors")
    memory.check_memory("a job", 10 << 20, "lower it", available=20 << 20)
    with pytest.raises(errors.VDNIFError, match=r"a job needs about 30 MiB of memory, more "
                       r"than the 20 MiB available here: lower it"):
        memory.check_memory("a job", 30 << 20, "lower it", available=20 << 20)
    monkeypatch.setenv("VDNIF_MEMORY_LIMIT", "1.5G")
    assert memory.available_bytes() <= 1.5 * (1 << 30)
    free = __import__("shutil").disk_usage(tmp_path).free
    memory.check_disk("a shard", free // 2, tmp_path / "new" / "folder", "lower it")
    with pytest.raises(errors.VDNIFError, match=r"a shard needs about .* on disk, more than "
                       r"the .* free at '.*': lower it"):
        memory.check_disk("a shard", free * 2, tmp_path / "new" / "folder", "lower it")
    assert not (tmp_path / "new").exists()


def test_a_frame_range_is_counted_before_it_is_built(core):
    animation = core("posed.animation")
    limits = core("limits")
    assert animation.parse_frames("1:4096") == list(range(1, 4097))
    assert animation.parse_frames("-1048574:1048574:1024") == list(
        range(-1048574, 1048575, 1024))
    started = datetime.datetime.now()
    with pytest.raises(core("errors").VDNIFError, match="more than the limit 4,096"):
        animation.parse_frames("1:4097")
    with pytest.raises(core("errors").VDNIFError, match="outside Blender's frames"):
        animation.parse_frames(f"0:{10**30}:{10**27}")
    assert (datetime.datetime.now() - started).total_seconds() < 1
    assert limits.MAX_FRAMES == limits.MAX_POSES


def test_an_offset_object_the_array_does_not_read_is_not_refused(files, core, extension):
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(files["blend:array_animated"]))
    cube = bpy.data.objects["Cube"]
    cube.modifiers["Array"].use_object_offset = False
    cube.modifiers["Array"].use_relative_offset = True
    core("blender.uncaptured").check_captured(cube)
    cube.modifiers["Array"].use_object_offset = True
    with pytest.raises(core("errors").VDNIFError, match="of object 'Offset', which is animated"):
        core("blender.uncaptured").check_captured(cube)


@pytest.mark.parametrize("fit, width, height", [("AUTO", 40, 30), ("AUTO", 30, 40),
                                                ("HORIZONTAL", 30, 40), ("VERTICAL", 40, 30)])
def test_a_shifted_camera_renders_the_pixels_blender_projects_to(empty_scene, core, fit, width,
                                                                 height):
    """Lens shift moves the image as Blender's own projection of a point does, for every
    sensor fit (it was ignored: the passes did not line up with Blender's render)."""
    import bpy

    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (3.0, -4.0, 2.0), (1.1, 0.1, 0.6)
    camera.data.lens, camera.data.sensor_fit = 35.0, fit
    camera.data.shift_x, camera.data.shift_y = 0.31, -0.17
    empty_scene.render.resolution_x, empty_scene.render.resolution_y = width, height
    bpy.context.view_layer.update()
    neural = core("posed.render")
    origins, directions = neural.view_rays(neural.camera_view(camera, width, height), width,
                                           height)
    assert_rays_hit_their_pixels(empty_scene, camera, origins, directions, width, height)


def test_a_camera_clip_range_hides_what_blender_clips(empty_scene, core):
    """An oracle network (the mesh itself) seen through a camera whose clip start cuts into
    the sphere's near side and whose clip end cuts off its far side: each pixel shows the
    first of Blender's own ray-cast hits whose depth (Blender's projection) lies within the
    clip range, at its distance from the camera."""
    import bpy
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=2.0)
    obj = bpy.context.active_object
    capture = core("blender.capture_scene").capture(obj, 12)
    neural = core("posed.render")
    model = oracle_scene_model(core, capture)
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.0, -12.0, 0.0), (np.pi / 2, 0.0, 0.0)
    camera.data.lens = 60.0
    camera.data.clip_start, camera.data.clip_end = 10.6, 13.2
    empty_scene.render.resolution_x, empty_scene.render.resolution_y = 24, 24
    bpy.context.view_layer.update()
    view = neural.camera_view(camera, 24, 24)
    origins, directions = neural.view_rays(view, 24, 24)
    with core("posed.geometry").PosedObject(obj, capture, "cpu") as posed_object:
        result = neural.render_view(model, posed_object, posed_object.geometry({"frame": 1.0}),
                                    view, 24, 24, references=True)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    hit, distance = np.zeros(len(origins), bool), np.zeros(len(origins))
    for index, (origin, direction) in enumerate(zip(origins, directions)):
        start = Vector(origin)
        for _ in range(4):                      # each surface crossing, near to far
            found, location, *_ = empty_scene.ray_cast(depsgraph, start, Vector(direction))
            if not found:
                break
            depth = world_to_camera_view(empty_scene, camera, location)[2]
            if depth > camera.data.clip_end:
                break
            if depth >= camera.data.clip_start:
                hit[index], distance[index] = True, (location - Vector(origin)).length
                break
            start = location + Vector(direction) * 1e-4
    assert 20 < hit.sum() < len(hit) - 20        # some pixels clipped away, some seen inside
    for passes in (result.predicted, result.true):
        assert (passes.hit != hit).sum() <= 2, (passes.hit != hit).sum()  # rays on the rim
        both = passes.hit & hit
        np.testing.assert_allclose(passes.distance[both] / result.world_scale[both],
                                   distance[both], atol=2e-3)


def test_the_framing_rule_keeps_near_pieces_and_leaves_far_ones(core):
    framing = core("geometry.framing")
    box = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    tetra = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    near, far = box + [1.9, 0, 0], box + [2.1 + 1, 0, 0]       # 0.9 and 1.1 sizes apart
    vertices = np.vstack([box, near, far, [[0.5, 0.5, 0.5], [0, -30, 0]]])
    triangles = np.vstack([tetra, tetra[:2] + 4, tetra + 8])
    kept = framing.framing(vertices, triangles, "Thing")
    assert kept.vertices.tolist() == [True] * 8 + [False] * 4 + [True, False]
    assert kept.triangles.tolist() == [True] * 6 + [False] * 4
    assert "1 loose vertex and 1 piece of 4 triangles" in kept.warning
    lo, hi = framing.framing_bounds(vertices, triangles)
    np.testing.assert_allclose([lo, hi], [[0, 0, 0], [2.9, 1, 1]])
    whole = framing.framing(box, tetra)
    assert whole.complete and whole.vertices.all()


def test_nothing_compared_is_an_error_that_says_why(core):
    metrics = core("inference.metrics")
    errors = core("errors")
    metrics.check_compared({"compared_rays": 3, "false_negative_rate": 0.1}, "Arm")
    metrics.check_compared({"compared_rays": 0, "false_negative_rate": 1.0}, "Arm")  # IoU 0
    with pytest.raises(errors.VDNIFError, match="'Arm' compared 0 rays: the true reference "
                       "hits nothing in any view"):
        metrics.check_compared({"compared_rays": 0, "false_negative_rate": None}, "Arm")


def test_a_model_trained_on_one_texture_refuses_another_or_none(empty_scene, core):
    """A red-textured cube's model on the same cube textured blue, or untextured: refused
    by the texture fingerprint (the mesh's own fingerprint holds no image pixels)."""
    import bpy

    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    image = bpy.data.images.new("Paint", 4, 4)
    image.pixels.foreach_set(np.tile([1.0, 0.0, 0.0, 1.0], 16).astype(np.float32))
    material = bpy.data.materials.new("Painted")
    material.use_nodes = True
    texture = material.node_tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    base = material.node_tree.nodes["Principled BSDF"].inputs["Base Color"]
    material.node_tree.links.new(texture.outputs["Color"], base)
    cube.data.materials.append(material)
    capture = core("blender.capture_scene").capture(cube, 8)
    metadata = capture_metadata(core, capture)
    fits, errors = core("inference.evaluation").check_model_fits, core("errors")
    fits("red.vdnif", metadata, capture.mesh, capture.grid)
    image.pixels.foreach_set(np.tile([0.0, 0.0, 1.0, 1.0], 16).astype(np.float32))
    blue = core("blender.read_mesh").read_rest_mesh(cube)
    assert (core("model.model_file").mesh_fingerprint(blue)
            == metadata.grid.mesh_fingerprint)              # what let it through before
    with pytest.raises(errors.VDNIFError, match=r"trained on other textures of 'Cube' \(now "
                       r"the images 'Paint' in its materials\)"):
        fits("red.vdnif", metadata, blue, capture.grid)
    material.node_tree.links.remove(base.links[0])
    with pytest.raises(errors.VDNIFError, match="now no image texture"):
        fits("red.vdnif", metadata, core("blender.read_mesh").read_rest_mesh(cube),
             capture.grid)
    older = dataclasses.replace(metadata, grid=dataclasses.replace(metadata.grid,
                                                                  texture_fingerprint=None))
    fits("old.vdnif", older, blue, capture.grid)
