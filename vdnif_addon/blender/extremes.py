"""Stress options: a uniform object scale and a procedural extreme pose.

``--scale S`` makes the object's rest geometry S times larger in its local space together with
its rig, so every pose is the same shape S times larger and every figure in object units
stays the same. ``--deform KIND:VALUE`` puts an extreme pose on top of each pose of the rig:
a pose dict gets the key ``"deform": {"object", "kind", "amount"}``, which ``poses.posed``
applies last through ``set_extreme``.

- armature (the bones that move the mesh): ``bend:DEG`` rotates every bone about its local X
  axis and ``twist:DEG`` about its own Y axis by DEG / chain depth, so the rotations along
  the longest chain sum to DEG; ``stretch:X`` / ``squash:X`` scale the chain's root bones by
  X along their Y axis, which the chain inherits (Blender's default Full scale inheritance).
- lattice: the points are moved in the object's proportions, normalized so the lattice's
  longest axis spans [-0.5, 0.5]: bend and twist by ``rig.bend_twist`` (its bend is the
  demo's parabolic bend: the far end is displaced by DEG/2 in radians of the axis length),
  stretch and squash by X along that axis about the lattice centre.

Stretch and squash do not preserve volume: the cross-section is kept, so squash:0.1 flattens
cells to a tenth of their height (the hardest case for the walk). The Armature modifier's
own Preserve Volume setting is left as it is.
"""

import math
from dataclasses import replace

import bpy
import numpy as np
from mathutils import Matrix

from ..errors import VDNIFError
from ..extreme_deform import ExtremeDeform, parse_scale
from .read_mesh import deform_modifiers
from .rig import bend_twist, influencing_bones, lattice_cells, offset_lattice

_BONE_CHANNELS = ("location", "rotation_quaternion", "rotation_euler", "rotation_axis_angle",
                  "scale")


def apply_stress(args, obj, spec):
    """Applies ``args.scale`` and ``args.deform`` (``cli.options.add_stress_options``) to
    ``obj``.

    Call once, right after the scene is loaded and before anything reads the rest mesh
    (capture). Scales ``obj`` and its rig now and returns the PoseSpec ``spec`` with the
    deform, so every pose drawn from it (``make_poses``, and ``evaluation_spec`` of it)
    carries the extreme pose. Raises VDNIFError for a deform of an object with no armature
    or lattice modifier.
    """
    if args.scale != 1:
        apply_scale(obj, args.scale)
    if args.deform is None:
        return spec
    if not deform_modifiers(obj):
        raise VDNIFError(f"cannot {args.deform.kind} '{obj.name}': it has no armature or "
                         f"lattice modifier")
    return replace(spec, deform=args.deform)


def apply_scale(obj, scale):
    """Makes ``obj``'s rest mesh ``scale`` times larger about its local origin, with its
    armature bones (envelopes, pose translations) or lattice, so each pose deforms the mesh
    into the same shape ``scale`` times larger. Meshes, armatures and lattices shared with
    other objects are scaled for them too."""
    scale = parse_scale(scale)
    obj.data.transform(Matrix.Scale(scale, 4), shape_keys=True)
    for modifier in deform_modifiers(obj):
        rig = modifier.object
        # The uniform scale about obj's origin, seen from the rig object's space.
        about = rig.matrix_world.inverted() @ obj.matrix_world
        pivot = Matrix.Translation(about.translation)
        in_rig = pivot @ Matrix.Scale(scale, 4) @ pivot.inverted()
        if modifier.type == "ARMATURE":
            _scale_armature(rig, in_rig, scale)
        else:
            rig.matrix_world = rig.matrix_world @ in_rig
    obj.data.update()
    bpy.context.view_layer.update()


def _scale_armature(armature, matrix, scale):
    """Bones by ``matrix`` (armature space); pose and keyed translations by ``scale``."""
    armature.data.transform(matrix)
    for bone in armature.pose.bones:
        bone.location = scale * bone.location
    action = armature.animation_data and armature.animation_data.action
    for curve in (action.fcurves if action else ()):
        if curve.data_path.startswith("pose.bones[") and curve.data_path.endswith(".location"):
            for key in curve.keyframe_points:
                for point in (key.co, key.handle_left, key.handle_right):
                    point[1] *= scale
            curve.update()


def set_extreme(deform):
    """Applies a pose's ``"deform"`` entry on top of the current pose of the object's rig;
    returns the function that undoes it."""
    obj = bpy.data.objects.get(deform["object"])
    if obj is None:
        raise VDNIFError(f"pose deforms object '{deform['object']}', which is not in the scene")
    extreme = ExtremeDeform(deform["kind"], float(deform["amount"]))
    bpy.context.view_layer.update()       # the lattice move reads the evaluated pose
    undo = [_armature_extreme(obj, m, extreme) if m.type == "ARMATURE"
            else _lattice_extreme(obj, m, extreme) for m in deform_modifiers(obj)]

    def undo_all():
        for step in reversed(undo):
            step()

    return undo_all


def _armature_extreme(obj, modifier, extreme):
    """Bend/twist every bone that moves ``obj``, or stretch/squash the chain's roots."""
    bones = modifier.object.pose.bones
    names = influencing_bones(obj, modifier)
    if not names:
        raise VDNIFError(f"armature '{modifier.object.name}' has no bone weighting mesh "
                         f"'{obj.name}'")
    depth = {name: _depth(bones[name].bone, names) for name in names}
    if extreme.kind in ("bend", "twist"):
        angle = math.radians(extreme.amount) / (max(depth.values()) + 1)
        extra = {name: Matrix.Rotation(angle, 4, "X" if extreme.kind == "bend" else "Y")
                 for name in names}
    else:
        extra = {name: Matrix.Diagonal((1.0, extreme.amount, 1.0, 1.0))
                 for name in names if depth[name] == 0}
    saved = [(bones[name], [tuple(getattr(bones[name], c)) for c in _BONE_CHANNELS])
             for name in extra]
    for bone, _ in saved:
        bone.matrix_basis = bone.matrix_basis @ extra[bone.name]

    def undo():
        for bone, values in saved:
            for channel, value in zip(_BONE_CHANNELS, values):
                setattr(bone, channel, value)

    return undo


def _depth(bone, names):
    """Ancestors of ``bone`` among ``names``."""
    parent, count = bone.parent, 0
    while parent is not None:
        count += parent.name in names
        parent = parent.parent
    return count


def _lattice_extreme(obj, modifier, extreme):
    """Moves the lattice's evaluated points by the extreme, written as offsets to every
    shape key (or the points), so the keys' blend lands exactly on the moved points."""
    lattice = modifier.object
    rest, _ = lattice_cells(lattice.data)
    to_object = np.array(obj.matrix_world.inverted() @ lattice.matrix_world)[:3, :3]
    spans = np.linalg.norm(to_object, axis=0) * np.ptp(rest, axis=0)   # object units
    axis = int(np.argmax(spans))
    if spans[axis] == 0:
        raise VDNIFError(f"lattice '{lattice.name}' has no extent to {extreme.kind}")
    # Lattice space -> object proportions with the longest axis in [-0.5, 0.5], and back.
    to_unit = np.linalg.norm(to_object, axis=0) / spans[axis]
    centre = 0.5 * (rest.min(axis=0) + rest.max(axis=0))
    evaluated = lattice.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.points
    current = np.array([point.co_deform for point in evaluated])
    unit = (current - centre) * to_unit
    if extreme.kind in ("bend", "twist"):
        angle = math.radians(extreme.amount)
        moved = bend_twist(unit, axis, angle if extreme.kind == "bend" else 0.0,
                            angle if extreme.kind == "twist" else 0.0)
    else:
        moved = unit.copy()
        moved[:, axis] *= extreme.amount
    offsets = moved / to_unit + centre - current
    return offset_lattice({"object": lattice.name,
                            "offsets": dict(enumerate(offsets.tolist()))})
