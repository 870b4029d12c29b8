"""Pose sources (DESIGN section 4): timeline frames and random poses of the bones and
lattice points that actually move the mesh.

A pose is a JSON-ready dict: ``{"frame": F}`` plus, for random poses,
``"bones": {name: [rx, ry, rz]}`` (local XYZ Euler radians) or
``"lattice": {"object": name, "offsets": {index: [dx, dy, dz]}}`` (lattice-space offsets),
and with a ``PoseSpec.deform`` the extreme pose ``"deform": {"object", "kind", "amount"}``
(see ``extremes``); ``REST_POSE`` is the undeformed rest pose. ``posed`` applies one and
restores the scene afterwards.

Evaluation poses are disjoint from the training poses by construction (DESIGN section 4):
``evaluation_spec`` names the training poses to avoid and the pose set; development and test
frames lie at different offsets in each step of the range (``evaluation_frames``), apart
from the training frames, and random poses that equal a training pose are drawn again; a
request that cannot be met is refused.
"""

import contextlib
import math
from dataclasses import replace

import bpy
import numpy as np
from mathutils import Euler

from ..errors import VDNIFError
from ..pose_sets import (
    FRAME_HALVINGS,
    FRAME_OFFSETS,
    POSE_SETS,
    TEST_POSES,
    PoseSpec,
    pose_key,
)
from .extremes import set_extreme
from .rig import influencing_bones, lattice_cells, moving_lattice_points, offset_lattice
from .scene_frame import at_frame, held

REST_POSE = {"rest": True}
# Frames closer than this are not distinct poses: Blender keeps the subframe as a float32
# (about 7 digits), and a thousandth of a frame is far below any animation's detail.
MIN_FRAME_SPACING = 1e-3


def evaluation_spec(spec, count=None, trained=None, pose_set=TEST_POSES):
    """The pose spec for evaluating a model trained on the poses of ``spec``: ``count``
    poses (default ``spec.count``) of the named ``pose_set`` (``pose_sets.POSE_SETS``: its
    own random seed; frames have none, so each set has its own frames, ``evaluation_frames``),
    disjoint from the training poses: ``trained`` (a model's stored training poses) when
    given, else those ``spec`` chooses."""
    if pose_set not in POSE_SETS:
        raise VDNIFError(f"unknown pose set '{pose_set}': choose one of "
                         f"{', '.join(POSE_SETS)}")
    return replace(spec, count=count or spec.count, seed=spec.seed + POSE_SETS[pose_set],
                   pose_set=pose_set,
                   avoid=replace(spec, avoid=None) if trained is None else tuple(trained))


def make_poses(obj, modifiers, spec):
    """The list of poses for ``obj`` deformed by ``modifiers`` according to ``spec``;
    disjoint from ``spec.avoid`` (raises a VDNIFError naming ``obj`` when they cannot be)."""
    scene = bpy.context.scene
    trained = spec.avoid
    if isinstance(trained, PoseSpec):
        trained = make_poses(obj, modifiers, trained)
    trained = list(trained or ())
    extreme = {} if spec.deform is None else {"deform": spec.deform.pose_key(obj)}
    if spec.source == "frames":
        try:
            frames = (frame_poses(scene.frame_start, scene.frame_end, spec.count)
                      if spec.pose_set is None else
                      evaluation_frames(scene.frame_start, scene.frame_end, spec.count,
                                        spec.pose_set,
                                        [p["frame"] for p in trained if _frame_only(p)]))
        except VDNIFError as exc:
            raise VDNIFError(f"'{obj.name}': {exc}") from None
        return [dict(pose, **extreme) for pose in frames]
    rng = np.random.default_rng(spec.seed)
    samplers = [_bone_sampler(obj, m, spec) if m.type == "ARMATURE"
                else _lattice_sampler(obj, m, spec) for m in modifiers]
    seen = {pose_key(pose) for pose in trained}
    poses, draws = [], 0
    while len(poses) < spec.count:
        # Each training pose can be drawn once more than in the training stream at most
        # (the same seed); more repeats mean the samplers cannot vary the pose at all.
        if draws == spec.count + len(trained):
            raise VDNIFError(
                f"'{obj.name}': random poses keep repeating the {len(trained)} training "
                f"poses (do the bones or lattice points that move it have no freedom?): "
                "evaluation poses cannot be disjoint from them")
        pose = {"frame": scene.frame_current}
        for sample in samplers:
            pose.update(sample(rng))
        pose.update(extreme)
        draws += 1
        if pose_key(pose) not in seen:
            poses.append(pose)
    return poses


def _frame_only(pose):
    return "frame" in pose and set(pose) <= {"frame", "deform"}


def frame_poses(start, end, count):
    """The ``count`` training frames: the centres of ``count`` equal steps of [start, end],
    at least MIN_FRAME_SPACING apart (else a VDNIFError)."""
    step = (end - start) / count
    if count > 1 and step < MIN_FRAME_SPACING:
        raise VDNIFError(f"the frame range {start:g}..{end:g} cannot hold {count} frames at "
                         f"least {MIN_FRAME_SPACING:g} frame apart: widen the range or ask "
                         "for fewer poses")
    return [{"frame": float(start + (i + 0.5) * step)} for i in range(count)]


def evaluation_frames(start, end, count, pose_set, avoid=()):
    """``count`` frames of the evaluation set ``pose_set`` spread over [start, end].

    Each set has its own frames (``pose_sets.FRAME_OFFSETS``): development frames a quarter
    and test frames three quarters of a step after each step's beginning, counted from
    ``start``, with steps of a frame, or of half a frame, a quarter and so on (at most
    FRAME_HALVINGS halvings) where the range holds fewer than ``count`` of them (the coarsest
    step that holds them). A frame's distance from ``start``, in units of the finest
    quarter step, is then a power of two times an odd number, 4k + 1 for a development frame
    and 4k + 3 for a test frame, whatever the step: the two sets never share a frame (nor,
    being at least a quarter step apart, come closer than 1/512 frame). Those closer than
    MIN_FRAME_SPACING to a training frame (``avoid``) are left out, and ``count`` of the rest
    are taken evenly (the one in the middle of each of ``count`` equal runs of them), so
    they cover the range. Raises a VDNIFError when even the finest step holds too few.
    """
    offset = FRAME_OFFSETS[pose_set]
    avoid = np.sort(np.unique(np.asarray(avoid, np.float64)))
    for halvings in range(FRAME_HALVINGS + 1):
        step = 0.5 ** halvings
        steps = max(math.floor((end - start) / step - offset) + 1, 0)
        frames = start + (np.arange(steps) + offset) * step
        if len(avoid):
            frames = frames[_distance_to(avoid, frames) >= MIN_FRAME_SPACING]
        if len(frames) >= count:
            picked = frames[((np.arange(count) + 0.5) * len(frames) / count).astype(np.int64)]
            return [{"frame": float(frame)} for frame in picked]
    apart = f" apart from the {len(avoid)} training frames" if len(avoid) else ""
    raise VDNIFError(f"the frame range {start:g}..{end:g} cannot hold {count} {pose_set} "
                     f"frames{apart} (steps of 1/{2 ** FRAME_HALVINGS} frame at the finest): "
                     "widen the range or ask for fewer poses")


def _distance_to(sorted_frames, frames):
    """Each of ``frames``' distance to the nearest of ``sorted_frames`` (non-empty)."""
    if len(sorted_frames) == 1:
        return np.abs(frames - sorted_frames[0])
    after = np.clip(np.searchsorted(sorted_frames, frames), 1, len(sorted_frames) - 1)
    return np.minimum(np.abs(frames - sorted_frames[after - 1]),
                      np.abs(frames - sorted_frames[after]))


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


def posing():
    """Whether the scene is being put in a pose (its frame changes are not the user's)."""
    return held()


@contextlib.contextmanager
def posed(pose):
    """Puts the scene in ``pose`` while inside; restores frame, bones and lattice after."""
    restore = []
    with at_frame(pose["frame"]):
        try:
            if "bones" in pose:
                restore.append(_set_bones(pose["bones"]))
            if "lattice" in pose:
                restore.append(offset_lattice(pose["lattice"]))
            if "deform" in pose:
                restore.append(set_extreme(pose["deform"]))
            bpy.context.view_layer.update()
            yield
        finally:
            for undo in reversed(restore):
                undo()


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


