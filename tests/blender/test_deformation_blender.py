"""The deformation's map D and its inverse transpose Jacobian J^-T against Blender's own
evaluation: on a posed armature, hits placed through the deformed voxels (rest hit mapped by
each cell's trilinear map, rest normal by J^-T) agree with BVHTree casts against the mesh
Blender evaluates, within the embedding's own error."""

import numpy as np
import pytest


@pytest.mark.slow
def test_voxel_mapped_hits_and_normals_match_blenders_casts_on_a_posed_armature(
        empty_scene, core):
    import bpy
    from mathutils.bvhtree import BVHTree

    poses = core("blender.poses")
    obj = core("blender.scenes").demo_scene("arm")
    # flat faces: Blender's cast gives the face normal, so the rest normal is the face's too
    obj.data.shade_flat()
    spec = poses.PoseSpec(count=1, seed=3, max_angle_deg=60.0)
    capture = core("blender.capture_scene").capture(obj, 48, spec, deform_corners=False)
    pose = capture.poses[0]
    assert "bones" in pose
    rays_module, traverse = core("tracing.rays"), core("tracing.traverse").traverse
    targets_of = core("tracing.groundtruth").segment_targets
    embedded_reference = core("tracing.references").embedded_reference
    with core("posed.geometry").PosedObject(obj, capture) as posed_object:
        geometry = posed_object.geometry(pose)
        direction = np.array([0.3, -1.0, 0.4]) / np.linalg.norm([0.3, -1.0, 0.4])
        origins, directions = rays_module.orbit_rays(
            geometry.vertices.min(0), geometry.vertices.max(0), direction, 64, 64)
        segments = traverse(geometry.cells, origins, directions)
        targets = targets_of(capture.mesh, posed_object.rest_caster, segments)
        embedded = embedded_reference(geometry.cells, segments, targets, len(directions))
        with poses.posed(pose):
            depsgraph = bpy.context.evaluated_depsgraph_get()
            evaluated = obj.evaluated_get(depsgraph)
            tree = BVHTree.FromObject(evaluated, depsgraph)
            mesh = evaluated.to_mesh()
            blender_vertices = np.array([v.co for v in mesh.vertices])
            evaluated.to_mesh_clear()
            casts = [tree.ray_cast(o, d) for o, d in zip(origins.tolist(), directions.tolist())]
    # the posed vertices the voxels were built from are Blender's evaluated ones (the bone moved)
    np.testing.assert_allclose(geometry.vertices, blender_vertices, atol=1e-5)
    rest = np.array([v.co for v in obj.data.vertices])
    assert np.abs(blender_vertices - rest).max() > 0.1 * capture.mesh.size

    hit = np.array([location is not None for location, *_ in casts])
    assert hit.sum() > 200
    # the masks differ only at silhouettes, where the embedding moves the outline slightly
    assert (hit != embedded.hit).mean() < 0.005
    both = hit & embedded.hit
    distance = np.array([c[3] if c[0] is not None else np.nan for c in casts])
    normal = np.array([c[1] if c[0] is not None else (np.nan,) * 3 for c in casts])
    h = capture.grid.voxel_size
    # D: the voxel-mapped hit along the ray is where Blender's surface is, within a small
    # share of a voxel on most rays (the trilinear map's error is second order in h)
    error = np.abs(embedded.distance[both] - distance[both])
    assert np.median(error) < 0.01 * h and np.quantile(error, 0.95) < 0.2 * h
    # J^-T: the rest normal carried by the inverse transpose Jacobian is Blender's face normal
    cos = np.clip((embedded.normal[both] * normal[both]).sum(1), -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))
    assert np.median(angle) < 1.0 and np.quantile(angle, 0.95) < 15.0
