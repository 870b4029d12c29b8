"""Pose sources (DESIGN section 4): timeline frames and random poses of the bones and
lattice points that actually move the mesh.

A pose is a JSON-ready dict: ``{"frame": F}`` plus, for random poses,
``"bones": {name: [rx, ry, rz]}`` (local XYZ Euler radians) or
``"lattice": {"object": name, "offsets": {index: [dx, dy, dz]}}`` (lattice-space offsets),
and with a ``PoseSpec.deform`` the extreme pose ``"deform": {"object", "kind", "amount"}``
(see ``extremes``). ``posed`` applies one and restores the scene afterwards.
"""

import contextlib
import math
from dataclasses import dataclass, replace

import bpy
import numpy as np
from mathutils import Euler

from ..errors import VDNIFError

POSE_SOURCES = ("random", "frames")
EVALUATION_SEED_OFFSET = 1_000_003


@dataclass(frozen=True)
class PoseSpec:
    """How to choose poses: ``count`` random poses from ``seed`` or frames of the range."""

    source: str = "random"
    count: int = 8
    seed: int = 0
    max_angle_deg: float = 45.0
    lattice_fraction: float = 0.3
    frame_offset: float = 0.0
    deform: object = None           # an extremes.ExtremeDeform added on top of every pose

    def __post_init__(self):
        if self.source not in POSE_SOURCES:
            raise VDNIFError(f"unknown pose source '{self.source}': "
                             f"choose one of {', '.join(POSE_SOURCES)}")
        if not 1 <= self.count <= 100_000:
            raise VDNIFError(f"pose count {self.count} is outside 1..100000")
        if not 0 < self.max_angle_deg <= 180:
            raise VDNIFError(f"maximum angle {self.max_angle_deg} degrees is outside (0, 180]")
        if not 0 < self.lattice_fraction <= 1:
            raise VDNIFError(f"lattice offset fraction {self.lattice_fraction} is outside (0, 1]")


def evaluation_spec(spec, count=None):
    """The pose spec for evaluation: other random seed, or frames half a step apart from
    the training frames, so every reported figure is on poses never trained on."""
    return replace(spec, count=count or spec.count, seed=spec.seed + EVALUATION_SEED_OFFSET,
                   frame_offset=0.5)


def make_poses(obj, modifiers, spec):
    """The list of poses for ``obj`` deformed by ``modifiers`` according to ``spec``."""
    scene = bpy.context.scene
    if spec.source == "frames":
        poses = frame_poses(scene.frame_start, scene.frame_end, spec.count, spec.frame_offset)
    else:
        rng = np.random.default_rng(spec.seed)
        samplers = [_bone_sampler(obj, m, spec) if m.type == "ARMATURE"
                    else _lattice_sampler(obj, m, spec) for m in modifiers]
        poses = []
        for _ in range(spec.count):
            pose = {"frame": scene.frame_current}
            for sample in samplers:
                pose.update(sample(rng))
            poses.append(pose)
    if spec.deform is not None:
        poses = [dict(pose, deform=spec.deform.pose_key(obj)) for pose in poses]
    return poses


def frame_poses(start, end, count, offset=0.0):
    """``count`` frames evenly spread over [start, end]; ``offset`` in (0, 1) shifts them by
    that fraction of a step, which gives evaluation frames disjoint from training ones."""
    step = (end - start) / count
    return [{"frame": float(start + (i + 0.5 + offset) * step)} for i in range(count)]


def influencing_bones(obj, modifier):
    """Bones of the armature that move ``obj``: weighted deform bones and their ancestors."""
    armature = modifier.object
    bones = armature.data.bones
    weighted = set()
    if modifier.use_bone_envelopes:
        weighted = {b.name for b in bones if b.use_deform}
    if modifier.use_vertex_groups:
        weighted |= {b.name for b in bones if b.use_deform and b.name in _weighted_groups(obj)}
    moving = set()
    for name in weighted:
        bone = bones[name]
        while bone is not None:
            moving.add(bone.name)
            bone = bone.parent
    return sorted(moving, key=lambda name: bones.find(name))


def moving_lattice_points(obj, modifier):
    """Indices of lattice points whose support reaches the mesh (the others move nothing)."""
    lattice = modifier.object
    rest, cell = lattice_cells(lattice.data)
    to_lattice = np.array(lattice.matrix_world.inverted() @ obj.matrix_world)
    vertices = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", vertices)
    vertices = vertices.reshape(-1, 3) @ to_lattice[:3, :3].T + to_lattice[:3, 3]
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    data = lattice.data
    interpolation = (data.interpolation_type_u, data.interpolation_type_v,
                     data.interpolation_type_w)
    reach = cell * np.array([1.0 if kind == "KEY_LINEAR" else 2.0 for kind in interpolation])
    inside = np.all((rest + reach > lo) & (rest - reach < hi), axis=1)
    return np.flatnonzero(inside).tolist()


def lattice_cells(data):
    """(P, 3) rest positions of the lattice points in lattice space and (3,) cell size."""
    rest = np.array([p.co for p in data.points])
    counts = np.array([data.points_u, data.points_v, data.points_w])
    return rest, np.ptp(rest, axis=0) / np.maximum(counts - 1, 1)


def _weighted_groups(obj):
    """Names of the vertex groups that hold a non-zero weight somewhere in the mesh."""
    used = set()
    for vertex in obj.data.vertices:
        used.update(g.group for g in vertex.groups if g.weight > 0)
    return {obj.vertex_groups[i].name for i in used}


def _bone_sampler(obj, modifier, spec):
    armature = modifier.object
    names = influencing_bones(obj, modifier)
    if not names:
        raise VDNIFError(f"armature '{armature.name}' has no bone weighting mesh '{obj.name}'")
    limits = np.array([_rotation_limits(armature.pose.bones[n], spec.max_angle_deg)
                       for n in names])                                  # (B, 2, 3)

    def sample(rng):
        angles = rng.uniform(limits[:, 0], limits[:, 1])
        return {"bones": {n: a.tolist() for n, a in zip(names, angles)}}

    return sample


def _rotation_limits(pose_bone, max_angle_deg):
    """(2, 3) min and max XYZ Euler angles: Limit Rotation constraint, locks, or the maximum."""
    limit = math.radians(max_angle_deg)
    lo, hi = np.full(3, -limit), np.full(3, limit)
    for constraint in pose_bone.constraints:
        if constraint.type == "LIMIT_ROTATION" and not constraint.mute:
            for axis, name in enumerate("xyz"):
                if getattr(constraint, f"use_limit_{name}"):
                    lo[axis] = max(lo[axis], getattr(constraint, f"min_{name}"))
                    hi[axis] = min(hi[axis], getattr(constraint, f"max_{name}"))
    locked = np.array(pose_bone.lock_rotation, bool)
    lo[locked] = hi[locked] = 0.0
    return np.stack([lo, np.maximum(lo, hi)])


def _lattice_sampler(obj, modifier, spec):
    lattice = modifier.object
    indices = moving_lattice_points(obj, modifier)
    reach = spec.lattice_fraction * lattice_cells(lattice.data)[1]

    def sample(rng):
        offsets = rng.uniform(-reach, reach, size=(len(indices), 3))
        return {"lattice": {"object": lattice.name,
                            "offsets": {int(i): o.tolist() for i, o in zip(indices, offsets)}}}

    return sample


@contextlib.contextmanager
def posed(pose):
    """Puts the scene in ``pose`` while inside; restores frame, bones and lattice after."""
    scene = bpy.context.scene
    frame = scene.frame_current, scene.frame_subframe
    restore = []
    try:
        whole = math.floor(pose["frame"])
        scene.frame_set(int(whole), subframe=pose["frame"] - whole)
        if "bones" in pose:
            restore.append(_set_bones(pose["bones"]))
        if "lattice" in pose:
            restore.append(_offset_lattice(pose["lattice"]))
        if "deform" in pose:
            from .extremes import set_extreme     # imported here: extremes builds on poses

            restore.append(set_extreme(pose["deform"]))
        bpy.context.view_layer.update()
        yield
    finally:
        for undo in reversed(restore):
            undo()
        scene.frame_set(frame[0], subframe=frame[1])


def _armature_of_bones(names):
    for obj in bpy.data.objects:
        if obj.type == "ARMATURE" and all(n in obj.pose.bones for n in names):
            return obj
    raise VDNIFError(f"no armature has the bones {', '.join(sorted(names))} of this pose")


def _set_bones(angles):
    armature = _armature_of_bones(list(angles))
    saved = []
    for name, xyz in angles.items():
        bone = armature.pose.bones[name]
        saved.append((bone, tuple(bone.rotation_quaternion), tuple(bone.rotation_euler),
                      tuple(bone.rotation_axis_angle)))
        euler = Euler(xyz, "XYZ")
        if bone.rotation_mode == "QUATERNION":
            bone.rotation_quaternion = euler.to_quaternion()
        elif bone.rotation_mode == "AXIS_ANGLE":
            axis, angle = euler.to_quaternion().to_axis_angle()
            bone.rotation_axis_angle = (angle, *axis)
        else:
            bone.rotation_euler = euler.to_matrix().to_euler(bone.rotation_mode)

    def undo():
        for bone, quaternion, euler, axis_angle in saved:
            bone.rotation_quaternion, bone.rotation_euler = quaternion, euler
            bone.rotation_axis_angle = axis_angle

    return undo


def _offset_lattice(spec):
    """Offsets lattice points; with shape keys every key block moves, so the blend of the
    keys moves by exactly the offset."""
    lattice = bpy.data.objects.get(spec["object"])
    if lattice is None or lattice.type != "LATTICE":
        raise VDNIFError(f"pose names lattice '{spec['object']}', which is not in the scene")
    data = lattice.data
    keys = data.shape_keys.key_blocks if data.shape_keys else None
    targets = [(block.data, "co") for block in keys] if keys else [(data.points, "co_deform")]
    saved = []
    for points, attribute in targets:
        co = np.empty(len(points) * 3, np.float32)
        points.foreach_get(attribute, co)
        saved.append((points, attribute, co))
        moved = co.reshape(-1, 3).copy()
        for index, offset in spec["offsets"].items():
            moved[int(index)] += offset
        points.foreach_set(attribute, moved.ravel())
    data.update_tag()

    def undo():
        for points, attribute, co in saved:
            points.foreach_set(attribute, co)
        data.update_tag()

    return undo
