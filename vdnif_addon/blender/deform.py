"""Deforms rest-space points (the voxel corners) with Blender's own modifiers.

A helper point object, parented to the mesh object so it shares its local space, carries a
copy of every deform modifier of the mesh with the same settings. Where a modifier reads
vertex groups, a Data Transfer modifier first gives each point the weights of the nearest
rest-surface point (barycentric interpolation of its face's weights) from a static copy of
the rest mesh. Evaluating the helper through the depsgraph gives the deformed corners.
"""

import bpy
import numpy as np

from ..errors import VDNIFError
from .read_mesh import deform_modifiers, deformers_disabled
from .uncaptured import check_captured

_NOT_COPIED = {"rna_type", "name", "type", "is_active", "is_override_data", "persistent_uid",
               "show_expanded", "execution_time", "use_pin_to_last"}


def check_deformers(obj):
    """Raises a VDNIFError for a deform modifier that cannot deform anything, and for any
    deformation of ``obj`` that the corners would not follow (``uncaptured``)."""
    for modifier in deform_modifiers(obj):
        if modifier.object is None:
            kind = modifier.type.lower()
            raise VDNIFError(f"{kind} modifier '{modifier.name}' of '{obj.name}' has no "
                             f"{kind} object")
    check_captured(obj)


class CornerDeformer:
    """Evaluates the deformed positions of fixed rest-space points of ``obj``.

    Use as a context manager: the helper objects are removed on exit.
    """

    def __init__(self, obj, points):
        """``points``: (C, 3) rest-space positions in ``obj``'s local coordinates."""
        check_deformers(obj)
        self.obj = obj
        self._created = []
        self.helper = self._new_object(f"{obj.name} VDNIF corners", points)
        self.helper.parent = obj
        modifiers = deform_modifiers(obj)
        if any(_reads_vertex_groups(m) for m in modifiers):
            self._transfer_weights(obj)
        for modifier in modifiers:
            _copy_modifier(modifier, self.helper)

    def deformed(self):
        """(C, 3) float64 deformed positions for the scene's current pose."""
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

    def _new_object(self, name, points, data=None):
        if data is None:
            data = bpy.data.meshes.new(name)
            data.vertices.add(len(points))
            data.vertices.foreach_set("co", np.asarray(points, np.float32).ravel())
        obj = bpy.data.objects.new(name, data)
        bpy.context.scene.collection.objects.link(obj)
        obj.hide_set(True)
        obj.hide_render = True
        self._created.append(obj)
        return obj

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
