"""Deforms rest-space points (the voxel corners) with Blender's own modifiers, or with the
surface Blender evaluates.

Where the armature and lattice modifiers are all that deform the mesh (``uncaptured``), a
helper point object, parented to the mesh object so it shares its local space, carries a
copy of every deform modifier of the mesh with the same settings. Where a modifier reads
vertex groups, a Data Transfer modifier first gives each point the weights of the nearest
rest-surface point (barycentric interpolation of its face's weights) from a static copy of
the rest mesh. Evaluating the helper through the depsgraph gives the deformed corners
(exact: the corners are deformed as the mesh is).

Anything else (driven or animated shape keys, Corrective Smooth, a subdivision after the
rig, Mesh Deform, Hook, geometry nodes...) is followed through the surface: the corners are
bound to the mesh as Blender evaluates it at rest and move with its evaluation in each pose
(``posed.binding``). A Subdivision Surface or Multires at the end of the stack is left out
of that surface (a helper object sharing the mesh data evaluates the stack without them):
the corners follow the cage, so their cost per pose does not grow with the subdivided
triangle count. A pose whose evaluated vertex or face count differs from the rest's is
refused in one line naming the object and the modifier that changes it.
"""

import contextlib

import bpy
import numpy as np

from ..errors import VDNIFError
from ..geometry.capture import (
    ARMATURE_COPY,
    CORNERS_FOLLOW,
    EVALUATED_SURFACE,
    SUBDIVIDED_SURFACE,
    SURFACE_BOUND,
)
from ..posed.binding import bind
from .read_mesh import deform_modifiers, deformers_disabled
from .uncaptured import POSITION_KEEPING, check_captured, check_followable

_NOT_COPIED = {"rna_type", "name", "type", "is_active", "is_override_data", "persistent_uid",
               "show_expanded", "execution_time", "use_pin_to_last"}


SUBDIVIDING = ("SUBSURF", "MULTIRES")
"""Modifiers left out of the surface the corners follow when they end the stack."""


def check_deformers(obj, follow=None):
    """How the corners of ``obj`` follow it (``ARMATURE_COPY`` or ``EVALUATED_SURFACE``:
    ``follow`` when given, else the copy wherever it captures every deformation); raises
    a VDNIFError for a deform modifier that cannot deform anything, and for a deformation
    of ``obj`` that the corners cannot follow (``uncaptured``)."""
    for modifier in deform_modifiers(obj):
        if modifier.object is None:
            kind = modifier.type.lower()
            raise VDNIFError(f"{kind} modifier '{modifier.name}' of '{obj.name}' has no "
                             f"{kind} object")
    check_followable(obj)
    if follow is not None:
        if follow not in CORNERS_FOLLOW:
            raise VDNIFError(f"unknown way for corners to follow '{obj.name}': '{follow}'")
        return follow
    try:
        check_captured(obj)
    except VDNIFError:
        return EVALUATED_SURFACE
    return ARMATURE_COPY


class CornerDeformer:
    """Evaluates the deformed positions of fixed rest-space points of ``obj``.

    Use as a context manager: the helper objects are removed on exit. ``follow`` says how
    (module docstring): ``ARMATURE_COPY`` or ``EVALUATED_SURFACE``.
    """

    def __init__(self, obj, points, follow=None, cage=True):
        """``points``: (C, 3) rest-space positions in ``obj``'s local coordinates;
        ``follow``: how (``check_deformers``: chosen from the object when None; a capture
        records its choice); ``cage``: with ``EVALUATED_SURFACE``, follow the surface
        without the subdivision that ends the stack (False: with it, as
        ``SUBDIVIDED_SURFACE`` does)."""
        self.follow = check_deformers(obj, follow)
        self.obj = obj
        self._created = []
        self.binding = None
        if self.follow in SURFACE_BOUND:
            self._bind_surface(obj, points, cage and self.follow != SUBDIVIDED_SURFACE)
            return
        self.helper = self._new_object(f"{obj.name} VDNIF corners", points)
        self.helper.parent = obj
        modifiers = deform_modifiers(obj)
        if any(_reads_vertex_groups(m) for m in modifiers):
            self._transfer_weights(obj)
        for modifier in modifiers:
            _copy_modifier(modifier, self.helper)

    @property
    def evaluated(self):
        """The object whose evaluation in a pose moves the corners: the helper carrying the
        copies, or the surface they are bound to (the mesh itself, or its cage's copy)."""
        return self.helper if self.binding is None else self.surface

    def deformed(self):
        """(C, 3) float64 deformed positions for the scene's current pose."""
        if self.binding is not None:
            return self.binding.moved(*self._posed_surface())
        depsgraph = bpy.context.evaluated_depsgraph_get()
        evaluated = self.helper.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            co = np.empty(len(mesh.vertices) * 3, np.float64)
            mesh.vertices.foreach_get("co", co)
        finally:
            evaluated.to_mesh_clear()
        return co.reshape(-1, 3)

    def close(self):
        for obj in reversed(self._created):
            data = obj.data
            bpy.data.objects.remove(obj)
            if data is not None and data.users == 0:
                bpy.data.meshes.remove(data)
        self._created.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _new_object(self, name, points, data=None, source=None):
        """A hidden helper object: a copy of ``source`` (modifiers, parent, animation;
        sharing its data), or one of ``data`` or of the vertices ``points``."""
        if data is None:
            data = bpy.data.meshes.new(name)
            data.vertices.add(len(points))
            data.vertices.foreach_set("co", np.asarray(points, np.float32).ravel())
        if source is not None:
            obj = source.copy()
            obj.name = name
        else:
            obj = bpy.data.objects.new(name, data)
        bpy.context.scene.collection.objects.link(obj)
        obj.hide_set(True)
        obj.hide_render = True
        self._created.append(obj)
        return obj

    def _bind_surface(self, obj, points, cage):
        """Binds ``points`` to the surface of ``obj`` evaluated at rest (its cage where a
        subdivision ends the stack and ``cage`` is True)."""
        self.surface = obj
        trailing = trailing_subdivision(obj) if cage else []
        if trailing:
            self.surface = self._new_object(f"{obj.name} VDNIF cage", None, data=obj.data,
                                            source=obj)
            for modifier in trailing:
                self.surface.modifiers.remove(self.surface.modifiers[modifier.name])
        with contextlib.ExitStack() as stack:
            depsgraph = stack.enter_context(deformers_disabled(obj))
            if self.surface is not obj:
                depsgraph = stack.enter_context(deformers_disabled(self.surface))
            evaluated = self.surface.evaluated_get(depsgraph)
            self._rest_counts = _counts(evaluated)
            vertices, normals = _read_surface(evaluated)
        self.rest_vertices = vertices
        size = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
        self.binding = bind(points, vertices, normals, scale=max(size, 1e-9) / _SCALE_PARTS)

    def _posed_surface(self):
        """(vertices, vertex normals) of the surface in the scene's current pose; refuses a
        vertex or face count other than the rest's. Only the surface read is counted: a
        cage's counts fix those of the subdivision left out of it, whose evaluation Blender
        defers until the subdivided mesh is read (so a pose's corners never pay it)."""
        evaluated = self.surface.evaluated_get(bpy.context.evaluated_depsgraph_get())
        found = _counts(evaluated)
        if found != self._rest_counts:
            raise VDNIFError(_topology_message(self.obj, self._rest_counts, found))
        return _read_surface(evaluated)

    def _transfer_weights(self, obj):
        """Adds the Data Transfer of vertex weights from a static rest copy of ``obj``."""
        with deformers_disabled(obj) as depsgraph:
            rest = bpy.data.meshes.new_from_object(
                obj.evaluated_get(depsgraph), preserve_all_data_layers=True, depsgraph=depsgraph)
        source = self._new_object(f"{obj.name} VDNIF weights", None, data=rest)
        for group in obj.vertex_groups:
            source.vertex_groups.new(name=group.name)
            self.helper.vertex_groups.new(name=group.name)
        transfer = self.helper.modifiers.new("Weights", "DATA_TRANSFER")
        transfer.object = source
        transfer.use_object_transform = False
        transfer.use_vert_data = True
        transfer.data_types_verts = {"VGROUP_WEIGHTS"}
        transfer.vert_mapping = "POLYINTERP_NEAREST"
        transfer.layers_vgroup_select_src = "ALL"
        transfer.layers_vgroup_select_dst = "NAME"


_SCALE_PARTS = 128
"""The binding's normal anchors reach this part of the surface's size out (a quarter of a
voxel at the default resolution; from 64 to 256 parts the embedding error of the small rigs
moves by a few percent)."""


def trailing_subdivision(obj):
    """The enabled Subdivision Surface and Multires modifiers that end ``obj``'s stack
    (only position-keeping modifiers after them): the surface before them is the cage the
    corners follow."""
    found = []
    for modifier in reversed(obj.modifiers):
        if not modifier.show_viewport or modifier.type in POSITION_KEEPING:
            continue
        if modifier.type not in SUBDIVIDING:
            break
        found.append(modifier)
    return found


def _counts(evaluated):
    """(vertices, faces) of an evaluated mesh object."""
    mesh = evaluated.data
    return len(mesh.vertices), len(mesh.polygons)


def _read_surface(evaluated):
    """(V, 3) float64 vertices and (V, 3) unit vertex normals of an evaluated mesh object."""
    mesh = evaluated.to_mesh()
    try:
        count = len(mesh.vertices)
        co = np.empty(count * 3, np.float64)
        mesh.vertices.foreach_get("co", co)
        normals = np.empty(count * 3, np.float64)
        mesh.vertex_normals.foreach_get("vector", normals)
    finally:
        evaluated.to_mesh_clear()
    return co.reshape(-1, 3), normals.reshape(-1, 3)


def _topology_message(obj, rest, posed):
    """The one line refusing a pose of ``obj`` whose (vertices, faces) ``posed`` differ from
    the rest's, naming the first modifier whose output differs (``_changing_modifier``)."""
    culprit = _changing_modifier(obj)
    where = f" (modifier '{culprit.name}', {culprit.type.lower().replace('_', ' ')})" \
        if culprit is not None else ""
    return (f"'{obj.name}' changes its topology between poses{where}: {rest[0]} vertices "
            f"and {rest[1]} faces at rest, {posed[0]} and {posed[1]} in this pose; only "
            "deformations that keep the vertices and faces can be followed")


def _changing_modifier(obj):
    """The first enabled modifier of ``obj`` after which the evaluated vertex or face count
    in the current pose differs from the same stack's with the deform modifiers off in the
    same frame, or None: found by evaluating each part of the stack."""
    enabled = [m for m in obj.modifiers if m.show_viewport]
    try:
        for end in range(1, len(enabled) + 1):
            for index, modifier in enumerate(enabled):
                modifier.show_viewport = index < end
            bpy.context.view_layer.update()
            posed = _counts(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()))
            with deformers_disabled(obj, rest_frame=False) as depsgraph:
                rest = _counts(obj.evaluated_get(depsgraph))
            if posed != rest:
                return enabled[end - 1]
    finally:
        for modifier in enabled:
            modifier.show_viewport = True
        bpy.context.view_layer.update()
    return None


def _reads_vertex_groups(modifier):
    return bool(modifier.vertex_group) or (
        modifier.type == "ARMATURE" and modifier.use_vertex_groups)


def _copy_modifier(modifier, target):
    """Adds to ``target`` a modifier of the same type with every writable setting copied."""
    copy = target.modifiers.new(modifier.name, modifier.type)
    for prop in modifier.bl_rna.properties:
        if prop.identifier in _NOT_COPIED or prop.is_readonly:
            continue
        setattr(copy, prop.identifier, getattr(modifier, prop.identifier))
    return copy
