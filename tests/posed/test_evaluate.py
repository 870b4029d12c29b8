"""Rendering a model on a Blender scene: camera rays against Blender's own projection,
world-space rendering against Blender's own ray casts, and the model/scene checks."""

import dataclasses

import numpy as np
import pytest
from camera_pixels import assert_rays_hit_their_pixels
from model_metadata import capture_metadata
from oracle_network import oracle_scene_model


@pytest.mark.parametrize("fit, width, height", [("AUTO", 40, 30), ("AUTO", 30, 40),
                                                ("HORIZONTAL", 30, 40), ("VERTICAL", 40, 30)])
def test_camera_rays_go_through_the_pixels_blender_projects_to(empty_scene, core, fit, width,
                                                                height):
    import bpy

    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location = (3.0, -4.0, 2.0)
    camera.rotation_euler = (1.1, 0.1, 0.6)
    camera.data.lens, camera.data.sensor_fit = 35.0, fit
    empty_scene.render.resolution_x, empty_scene.render.resolution_y = width, height
    bpy.context.view_layer.update()
    origins, directions = core("posed.render").camera_rays(camera, width, height)
    assert origins.shape == (width * height, 3)
    np.testing.assert_allclose(origins, np.broadcast_to(camera.location, origins.shape))
    assert_rays_hit_their_pixels(empty_scene, camera, origins, directions, width, height)


def test_camera_errors_name_the_object(empty_scene, core):
    import bpy

    neural = core("posed.render")
    errors = core("errors")
    ortho = bpy.data.objects.new("Flat", bpy.data.cameras.new("Flat"))
    ortho.data.type = "ORTHO"
    empty = bpy.data.objects.new("Nothing", None)
    for camera, message in ((ortho, "camera 'Flat' is ortho"),
                            (empty, "object 'Nothing' is an empty, not a camera"),
                            (None, "no camera")):
        with pytest.raises(errors.VDNIFError, match=message):
            neural.camera_rays(camera, 8, 8)
    with pytest.raises(errors.VDNIFError, match="no camera named 'Ghost'"):
        core("blender.scenes").find_camera("Ghost")


def test_world_rays_of_a_moved_scaled_object_match_blenders_ray_cast(empty_scene, core):
    """An oracle network renders the embedded reference; on the rest pose that is the mesh
    itself, so world distances must equal Blender's own scene ray cast."""
    import bpy
    from mathutils import Vector

    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=1.0)
    obj = bpy.context.active_object
    obj.location, obj.rotation_euler, obj.scale = (1.0, -2.0, 0.5), (0.3, 0.2, 0.9), (2.0,) * 3
    bpy.context.view_layer.update()
    capture = core("blender.capture_scene").capture(obj, 12)
    neural = core("posed.render")
    model = oracle_scene_model(core, capture)
    camera = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    empty_scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (1.0, -12.0, 0.5), (np.pi / 2, 0.0, 0.0)
    bpy.context.view_layer.update()
    origins, directions = neural.camera_rays(camera, 32, 24)
    result = neural.render_rays(obj, capture, model, {"frame": 1.0}, origins, directions,
                                references=True)
    np.testing.assert_allclose(result.world_scale, 0.5)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    blender = [empty_scene.ray_cast(depsgraph, Vector(o), Vector(d))
               for o, d in zip(origins, directions)]
    hit = np.array([b[0] for b in blender])
    assert hit.sum() > 100
    np.testing.assert_array_equal(result.predicted.hit, hit)
    world = result.predicted.distance[hit] / result.world_scale[hit]
    blender_distance = np.array([(b[1] - Vector(o)).length for b, o in zip(blender, origins)
                                 if b[0]])
    np.testing.assert_allclose(world, blender_distance, atol=1e-4)
    np.testing.assert_array_equal(result.true.hit, hit)
    np.testing.assert_allclose(result.embedded.distance, result.predicted.distance, atol=1e-5)


def test_a_model_for_another_object_or_resolution_is_refused(empty_scene, core):
    capture = core("blender.capture_scene").capture(core("blender.scenes").demo_scene("arm"), 16,
                                              core("blender.poses").PoseSpec(count=1))
    grid = capture.grid
    metadata = capture_metadata(core, capture)
    fits = core("inference.evaluation").check_model_fits
    fits("m.vdnif", metadata, capture.mesh, grid)
    errors = core("errors")
    cases = [
        (dataclasses.replace(metadata, object="Suzanne"), "trained on 'Suzanne' at resolution 16"),
        (dataclasses.replace(metadata, grid=dataclasses.replace(metadata.grid, resolution=32)),
         "not on 'Arm' at resolution 16"),
        (dataclasses.replace(metadata, grid=dataclasses.replace(
            metadata.grid, voxel_size=0.2, extent=0.2 * max(metadata.grid.dims))),
         "the mesh of 'Arm' has changed"),
        (dataclasses.replace(metadata, grid=dataclasses.replace(metadata.grid,
                                                                mesh_fingerprint="0" * 64)),
         "another version of the mesh of 'Arm'"),
        (capture_metadata(core, capture, network_config=core("settings").NetworkConfig(
            heads=core("settings").Heads(albedo=False, material_count=2)).to_dict(),
            material_slots=[0, 1], albedo_table=[[0.5] * 3] * 2),
         "knows 2 materials, 'Arm' has 1"),
    ]
    for other, message in cases:
        with pytest.raises(errors.VDNIFError, match=message):
            fits("m.vdnif", other, capture.mesh, grid)


def test_a_ray_leaving_through_the_other_half_of_its_folded_entry_face_walks_on(empty_scene,
                                                                                core):
    """Regression: on this unseen arm pose one orbit ray enters a cell through one triangle
    of a non-planar face and leaves through the other; the walk re-seeked from just past
    its entry, where the float32 BVH found the entry again, forever."""
    steps, rays = core("blender.steps"), core("tracing.rays")
    obj = core("blender.scenes").demo_scene("arm")
    evaluated = steps.evaluation_poses(obj, 32, core("blender.poses").PoseSpec(count=4))
    with core("posed.geometry").PosedObject(obj, evaluated) as posed_object:
        geometry = posed_object.geometry(evaluated.poses[1])
        origins, directions = rays.orbit_rays(geometry.vertices.min(0),
                                              geometry.vertices.max(0),
                                              rays.orbit_viewpoints(4)[1], 128, 128)
        segments = core("tracing.traverse").traverse(geometry.cells, origins[5680:5685],
                                             directions[5680:5685], max_steps=100)
    assert segments.truncated == 0
    assert len(segments) > 5 and (segments.t1 >= segments.t0).all()
