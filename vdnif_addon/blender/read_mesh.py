"""Reads an object's rest mesh and material albedo sources from Blender."""

import contextlib
import os
import sys

import bpy
import numpy as np

from ..errors import VDNIFError
from ..geometry.attributes import has_area
from ..geometry.framing import framing
from ..geometry.restmesh import Albedo, RestMesh
from ..limits import MAX_OBJECT_SIZE, MIN_OBJECT_SIZE
from ..text import article
from .scene_frame import at_frame

DEFORM_MODIFIER_TYPES = ("ARMATURE", "LATTICE")
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)
_SAID = set()
"""The warnings printed already by this process."""


def check_mesh_object(obj):
    """Raises a VDNIFError unless ``obj`` is a mesh object with faces."""
    if obj is None:
        raise VDNIFError("no object given")
    for block in (obj, obj.data):
        # A linked block whose library file is missing loads as a placeholder (an object
        # becomes an empty): say which library, not what the placeholder is.
        if block is not None and getattr(block, "is_missing", False):
            library = block.library
            where = (f"the library '{bpy.path.abspath(library.filepath)}'" if library
                     else "a library")
            raise VDNIFError(f"object '{obj.name}' is linked from {where}, which is missing: "
                             "restore the library file or make the object local")
    if obj.type != "MESH":
        raise VDNIFError(f"object '{obj.name}' is {article(obj.type.lower())}, not a mesh")
    if len(obj.data.polygons) == 0:
        raise VDNIFError(f"mesh object '{obj.name}' is empty: it has no faces")


def deform_modifiers(obj):
    """The enabled modifiers that deform ``obj`` with a pose (armature, lattice)."""
    return [m for m in obj.modifiers if m.type in DEFORM_MODIFIER_TYPES and m.show_viewport]


@contextlib.contextmanager
def deformers_disabled(obj, rest_frame=True):
    """Evaluates ``obj`` at rest while inside (DESIGN section 4): deform modifiers switched
    off, and with ``rest_frame`` at the scene's first frame, whatever frame it shows, so that
    what moves over the frames (an animated shape key, a node tree's time) gives one rest
    for training, evaluation and the panel's renders alike (False: at the current frame, to
    compare a pose with its own stack undeformed)."""
    scene = bpy.context.scene
    moved = rest_frame and (scene.frame_current, scene.frame_subframe) != (scene.frame_start, 0)
    modifiers = deform_modifiers(obj)
    with at_frame(float(scene.frame_start)) if moved else contextlib.nullcontext():
        for modifier in modifiers:
            modifier.show_viewport = False
        bpy.context.view_layer.update()
        try:
            yield bpy.context.evaluated_depsgraph_get()
        finally:
            for modifier in modifiers:
                modifier.show_viewport = True
            bpy.context.view_layer.update()


def evaluated_surface(obj, rest):
    """The evaluated (deformed) mesh of the current pose in local space, on the rest mesh's
    triangulation: vertices (V,3) float64 and corner normals (T,3,3) float32.

    Blender re-triangulates quads by their deformed shape, so its own loop triangles may
    pick the other diagonal of a non-planar quad; keeping the rest triangles (same loops)
    makes the deformed mesh exactly the rest mesh with moved vertices.
    """
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    try:
        source = rest.source_vertices
        if (len(mesh.vertices) != len(rest.vertices if source is None else source)
                or len(mesh.loops) <= rest.triangle_loops.max()):
            raise VDNIFError(f"'{obj.name}': a modifier changes the mesh topology between rest "
                             f"and pose; only deform modifiers are supported")
        normals = np.empty(len(mesh.loops) * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        vertices = _vertices(mesh)
        return (vertices if source is None else vertices[source],
                normals.reshape(-1, 3)[rest.triangle_loops])
    finally:
        evaluated.to_mesh_clear()


def read_rest_mesh(obj):
    """The rest mesh of ``obj``: evaluated at the scene's first frame with its deform
    modifiers disabled (``deformers_disabled``)."""
    check_mesh_object(obj)
    with deformers_disabled(obj) as depsgraph:
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            return _rest_mesh_from(obj, mesh)
        finally:
            evaluated.to_mesh_clear()


def _rest_mesh_from(obj, mesh):
    mesh.calc_loop_triangles()
    if len(mesh.loop_triangles) == 0:
        raise VDNIFError(f"mesh object '{obj.name}' is empty: it has no faces")
    loops = _loop_triangle_array(mesh, "loops", 3, np.int64)
    vertices = _vertices(mesh)
    if not np.isfinite(vertices).all():
        raise VDNIFError(f"mesh object '{obj.name}' has vertices at infinite or NaN positions")
    triangles = _loop_triangle_array(mesh, "vertices", 3, np.int32)
    frame = framing(vertices, triangles, obj.name)
    kept = frame.triangles
    if not frame.complete:          # far pieces left out: the rest mesh is the body's
        if frame.warning not in _SAID:        # once a run, not at every read of the mesh
            _SAID.add(frame.warning)
            print(f"vdnif: warning: {frame.warning}", file=sys.stderr, flush=True)
        renumbered = np.cumsum(frame.vertices) - 1
        vertices, loops = vertices[frame.vertices], loops[kept]
        triangles = renumbered[triangles[kept]].astype(np.int32)
    size = float(np.ptp(vertices, axis=0).max())
    if not MIN_OBJECT_SIZE <= size <= MAX_OBJECT_SIZE:
        raise VDNIFError(f"mesh object '{obj.name}' is {size:.3g} units across, outside the "
                         f"supported {MIN_OBJECT_SIZE:g}..{MAX_OBJECT_SIZE:g} (scale it, or "
                         "change the scene's units)")
    if not has_area(vertices[triangles]).any():
        raise VDNIFError(f"mesh object '{obj.name}' has no area: all its {len(triangles)} "
                         f"triangles are degenerate (collinear or repeated corners)")
    rest = RestMesh(
        name=obj.name,
        vertices=vertices,
        triangles=triangles,
        corner_normals=_loop_triangle_array(mesh, "split_normals", 9, np.float32)
        .reshape(-1, 3, 3)[kept],
        material_index=_loop_triangle_array(mesh, "material_index", 1, np.int32).ravel()[kept],
        triangle_loops=loops,
        source_vertices=None if frame.complete else frame.vertices,
    )
    if not frame.complete:
        rest.warnings.append(frame.warning)
    if mesh.uv_layers.active is not None:
        uv = np.empty(len(mesh.loops) * 2, np.float32)
        mesh.uv_layers.active.uv.foreach_get("vector", uv)
        rest.uvs = uv.reshape(-1, 2)[loops]
    # Model only what the scene requires: the materials of the slots that faces use (a
    # face's index past the last slot renders with the last one, as in Blender).
    slot_index = np.clip(rest.material_index, 0, max(len(obj.material_slots), 1) - 1)
    used, rest.material_index = np.unique(slot_index, return_inverse=True)
    rest.material_index = rest.material_index.astype(np.int32).ravel()
    rest.used_slots = used.astype(np.int32)
    rest.albedo = [_albedo(obj.material_slots[int(slot)].material, obj, rest,
                           rest.material_index == index) for index, slot in enumerate(used)
                   ] if len(obj.material_slots) else [
        Albedo("constant", np.array(DEFAULT_ALBEDO, np.float32), source="no material")]
    for albedo in rest.albedo:
        if not (np.isfinite(albedo.color).all() and (albedo.texture is None
                                                     or np.isfinite(albedo.texture).all())):
            raise VDNIFError(f"'{obj.name}': the albedo of '{albedo.source}' has non-finite "
                             "(NaN or infinite) values")
    attribute = next((a.source for a in rest.albedo if a.kind == "attribute"), None)
    if attribute is not None:
        rest.corner_colors = _corner_colors(obj, mesh, attribute, loops)
    return rest


def _vertices(mesh):
    co = np.empty(len(mesh.vertices) * 3, np.float64)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def _loop_triangle_array(mesh, attribute, width, dtype):
    values = np.empty(len(mesh.loop_triangles) * width, dtype)
    mesh.loop_triangles.foreach_get(attribute, values)
    return values.reshape(-1, width)


def _albedo(material, obj, rest, faces=None):
    """The albedo source of one material slot (Principled BSDF Base Color) on the triangles
    ``faces`` (bool) of ``rest``."""
    if material is None:
        return Albedo("constant", np.array(DEFAULT_ALBEDO, np.float32), source="empty slot")
    principled = _principled_node(material)
    if principled is None:
        return Albedo("constant", np.array(material.diffuse_color[:3], np.float32),
                      source=material.name)
    base = principled.inputs["Base Color"]
    constant = np.array(base.default_value[:3], np.float32)
    if not base.is_linked:
        return Albedo("constant", constant, source=material.name)
    node = base.links[0].from_node
    if node.type == "TEX_IMAGE" and node.image is not None:
        _check_tiles(node.image, material, obj, None if rest.uvs is None or faces is None
                     else rest.uvs[faces])
        return Albedo("texture", constant, texture=_image_pixels(node.image, material),
                      extension=node.extension, source=node.image.name)
    if node.type == "VERTEX_COLOR" or (node.type == "ATTRIBUTE"
                                       and node.attribute_type == "GEOMETRY"):
        name = node.layer_name if node.type == "VERTEX_COLOR" else node.attribute_name
        name = name or (obj.data.color_attributes.active_color_name or "")
        if name in obj.data.color_attributes:
            return Albedo("attribute", constant, source=name)
    rest.warnings.append(f"material '{material.name}': Base Color is driven by a "
                         f"'{node.bl_label}' node, which is not supported; its constant is used")
    return Albedo("constant", constant, source=material.name)


def _check_tiles(image, material, obj, uvs):
    """Refuses a UDIM image whose tiles that faces use (``uvs`` (T, 3, 2) of the material's
    triangles, each at its centre) are missing, which would read as black, or are more than
    the one tile an image's pixels give (the first), which would read as that tile."""
    if image.source != "TILED" or uvs is None or len(uvs) == 0:
        return
    centre = np.floor(uvs.mean(axis=1)).astype(np.int64)
    used = sorted(set((1001 + centre[:, 0] + 10 * centre[:, 1]).tolist()))
    tiles = {tile.number: tile for tile in image.tiles}
    pattern = bpy.path.abspath(image.filepath)
    for number in used:
        path = pattern.replace("<UDIM>", str(number)) if "<UDIM>" in pattern else None
        tile = tiles.get(number)
        if (tile is None or tile.size[0] == 0 or (path is not None and image.packed_file is None
                                                  and not os.path.isfile(path))):
            raise VDNIFError(f"image '{image.name}' of material '{material.name}' lacks its "
                             f"UDIM tile {number}" + (f" (file '{path}')" if path else "")
                             + f", which faces of '{obj.name}' use: it would read as black")
    first = image.tiles[0].number if len(image.tiles) else 1001
    if used != [first]:
        raise VDNIFError(f"image '{image.name}' of material '{material.name}' is a UDIM image "
                         f"and faces of '{obj.name}' use its tiles {', '.join(map(str, used))}: "
                         f"VDNIF reads one tile ({first}); move the UVs into it or bake one "
                         "texture")


def _principled_node(material):
    if not material.use_nodes or material.node_tree is None:
        return None
    nodes = material.node_tree.nodes
    output = next((n for n in nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output), None)
    if output is not None and output.inputs["Surface"].is_linked:
        node = output.inputs["Surface"].links[0].from_node
        if node.type == "BSDF_PRINCIPLED":
            return node
    return next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)


def _image_pixels(image, material):
    """(H, W, 3) float32 linear RGB of an image, bottom row first as Blender stores it."""
    if not image.has_data:
        _try_load(image)
    width, height = image.size
    if width == 0 or height == 0 or not image.has_data:
        raise VDNIFError(f"image '{image.name}' of material '{material.name}' cannot be read "
                         f"(missing file '{image.filepath}'?)")
    pixels = np.empty(width * height * image.channels, np.float32)
    image.pixels.foreach_get(pixels)
    rgb = pixels.reshape(height, width, image.channels)[..., :3]
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        rgb = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def _try_load(image):
    try:
        image.reload()
    except RuntimeError:
        pass


def _corner_colors(obj, mesh, name, loops):
    """(T, 3, 3) linear colors of the color attribute ``name`` at each triangle corner."""
    attribute = mesh.color_attributes.get(name)
    if attribute is None:
        raise VDNIFError(f"color attribute '{name}' of '{obj.name}' is missing after evaluation")
    colors = np.empty(len(attribute.data) * 4, np.float32)
    attribute.data.foreach_get("color", colors)
    colors = colors.reshape(-1, 4)[:, :3]
    if attribute.domain == "POINT":
        loop_vertex = np.empty(len(mesh.loops), np.int64)
        mesh.loops.foreach_get("vertex_index", loop_vertex)
        return colors[loop_vertex[loops]]
    return colors[loops]
