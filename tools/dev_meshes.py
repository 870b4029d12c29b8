"""The development meshes: nine meshes of varied shape built with bpy alone (primitives,
Suzanne, text, metaballs, the Skin modifier, a displacement; no third-party assets), each
written as an OBJ file with the procedural rig it is trained with (``train --mesh FILE --rig
RIG``). None of them is one of the meshes the recipe was tuned on (the arm, the lattice
Suzanne, spot, the bunny); each stresses one kind of shape, and every one is a closed
surface of at most 50k triangles, a couple of units across.

    python tools/dev_meshes.py --out out/dev-meshes [--mesh text --mesh shell]

Every mesh is the same on every run: random placements come from a fixed seed, the
displacement's noise is Blender's procedural Clouds texture at fixed settings.
"""

import argparse
import math
import pathlib
import sys

import bpy  # isort: skip  (Blender's modules come with it)
import numpy as np

SEED = 0
"""The seed of every random placement (the horns' directions)."""

# name: (rig, what the mesh stresses). Ordered from the least like the tuning meshes.
MESHES = {
    "text": ("armature", "flat parts and sharp edges: the extruded, bevelled word VDNIF on a bar"),
    "shell": ("lattice", "a thin shell: an open hemisphere 2 % of its radius thick"),
    "horns": ("armature", "thin limbs: a sphere with six thin cone horns"),
    "slab": ("armature", "flat parts with holes: a slab with three round holes through it"),
    "creature": ("armature", "a creature: a four-legged Skin-modifier animal with a tail"),
    "torus": ("lattice", "a hole: a torus, its tube a quarter of its radius"),
    "rock": ("lattice", "a rough surface: an icosphere displaced by a Clouds texture"),
    "blob": ("lattice", "smooth necks: a metaball blob of seven balls"),
    "monkey": ("armature", "a creature head: Suzanne with her eyes, smoothed, on an armature"),
}
MAX_TRIANGLES = 50_000
LONGEST_EDGE = 0.08
"""Flat faces (the text, the slab, the horns' sides) are split until no edge is longer: about
a voxel at the default resolution for meshes of this size. A rig moves a mesh's vertices
only, so a long triangle stays straight where the rig bends; the voxel embedding bends it
(a first build with edges of up to 3 units had 16 % holes against the true reference, from
the embedding alone). A mesh rigged for bending has such edges split already."""


def _reset():
    bpy.ops.wm.read_homefile(use_empty=True)


def _link(name, mesh):
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _applied(obj, name=None):
    """A new object holding ``obj``'s evaluated mesh (its modifiers applied, curves and
    metaballs converted); ``obj`` is removed."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = bpy.data.meshes.new_from_object(obj.evaluated_get(depsgraph))
    name = name or obj.name
    bpy.data.objects.remove(obj)
    return _link(name, mesh)


def _split_long_edges(obj, longest=LONGEST_EDGE):
    """Splits ``obj``'s edges in halves until none is longer than ``longest`` (its shape is
    unchanged: new vertices lie on the old faces), leaving triangles: each pass halves the
    longest edge of every triangle that has one too long, and both triangles beside it. At
    most MAX_TRIANGLES at LONGEST_EDGE, more in proportion to the area of a shorter edge's
    triangle."""
    limit = int(MAX_TRIANGLES * max(1.0, (LONGEST_EDGE / longest) ** 2))
    mesh = obj.data
    mesh.calc_loop_triangles()
    vertices = [tuple(vertex.co) for vertex in mesh.vertices]
    triangles = {tuple(triangle.vertices) for triangle in mesh.loop_triangles}

    def length(a, b):
        return math.dist(vertices[a], vertices[b])

    while True:
        beside = {}
        for triangle in triangles:
            for k in range(3):
                beside[frozenset((triangle[k], triangle[(k + 1) % 3]))] = beside.get(
                    frozenset((triangle[k], triangle[(k + 1) % 3])), []) + [triangle]
        long = set()
        for a, b, c in triangles:
            edge = max(((a, b), (b, c), (c, a)), key=lambda pair: length(*pair))
            if length(*edge) > longest:
                long.add(frozenset(edge))
        if not long:
            break
        # Longest first: a long edge is never starved by its shorter neighbours' splits.
        for edge in sorted(long, key=lambda edge: -length(*sorted(edge))):
            a, b = sorted(edge)
            if not all(t in triangles for t in beside[edge]):
                continue            # a triangle beside it was split this pass: next pass
            middle = len(vertices)
            vertices.append(tuple((p + q) / 2 for p, q in zip(vertices[a], vertices[b])))
            for triangle in beside[edge]:
                triangles.discard(triangle)
                k = next(k for k in range(3)
                         if {triangle[k], triangle[(k + 1) % 3]} == {a, b})
                first, second, third = triangle[k], triangle[(k + 1) % 3], triangle[(k + 2) % 3]
                triangles.add((first, middle, third))
                triangles.add((middle, second, third))
        if len(triangles) > limit:
            raise RuntimeError(f"'{obj.name}': over {limit} triangles while splitting")
    split = bpy.data.meshes.new(mesh.name)
    split.from_pydata(vertices, [], sorted(triangles))
    split.validate()
    obj.data = split
    return obj


def _primitive(operator, **options):
    operator(**options)
    return bpy.context.active_object


def _boolean(obj, cutters, operation):
    """``obj`` with each of ``cutters`` joined (UNION) or cut away (DIFFERENCE) by the exact
    Boolean solver, applied; the cutters are removed."""
    for index, cutter in enumerate(cutters):
        modifier = obj.modifiers.new(f"Boolean {index}", "BOOLEAN")
        modifier.operation, modifier.solver, modifier.object = operation, "EXACT", cutter
    result = _applied(obj)
    for cutter in cutters:
        bpy.data.objects.remove(cutter)
    return result


def text(longest=LONGEST_EDGE):
    curve = bpy.data.curves.new("Text", "FONT")
    curve.body = "VDNIF"
    curve.size, curve.extrude, curve.resolution_u = 1.0, 0.12, 4
    curve.bevel_depth, curve.bevel_resolution = 0.02, 1
    curve.align_x, curve.align_y = "CENTER", "CENTER"
    obj = _applied(_link_curve("Text", curve))
    # The conversion leaves the caps and the bevelled sides unjoined: merge their seams.
    import bmesh

    editable = bmesh.new()
    editable.from_mesh(obj.data)
    bmesh.ops.remove_doubles(editable, verts=editable.verts, dist=1e-5)
    editable.to_mesh(obj.data)
    editable.free()
    # A bar under the letters joins them into one piece (a loose letter a body's size away
    # would be left out of the framing, and so of the training).
    bar = _primitive(bpy.ops.mesh.primitive_cube_add, size=1.0, location=(0, -0.36, 0))
    bar.scale = (3.0, 0.16, 0.16)
    bpy.ops.object.transform_apply(scale=True)
    obj = _boolean(obj, [bar], "UNION")
    obj.name = "Text"
    return _split_long_edges(obj, longest)


def _link_curve(name, curve):
    obj = bpy.data.objects.new(name, curve)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def shell(radius=1.0, thickness=0.02):
    sphere = _primitive(bpy.ops.mesh.primitive_uv_sphere_add, segments=64, ring_count=32,
                        radius=radius)
    mesh = sphere.data
    # Keep the lower half: the open rim is at z = 0.
    import bmesh

    editable = bmesh.new()
    editable.from_mesh(mesh)
    bmesh.ops.delete(editable, geom=[v for v in editable.verts if v.co.z > 1e-6],
                     context="VERTS")
    editable.to_mesh(mesh)
    editable.free()
    solidify = sphere.modifiers.new("Solidify", "SOLIDIFY")
    solidify.thickness, solidify.offset, solidify.use_even_offset = thickness, -1.0, True
    solidify.use_rim = True
    obj = _applied(sphere, "Shell")
    obj.data.shade_smooth()
    return obj


def horns(count=6, length=0.9, base=0.07, longest=LONGEST_EDGE):
    body = _primitive(bpy.ops.mesh.primitive_uv_sphere_add, segments=48, ring_count=24,
                      radius=0.6)
    rng = np.random.default_rng(SEED)
    cutters = []
    for _ in range(count):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        # A cone from inside the sphere out along ``direction``, its tip length past it.
        centre = direction * (0.5 + length / 2)
        cone = _primitive(bpy.ops.mesh.primitive_cone_add, vertices=16, radius1=base,
                          radius2=0.0, depth=length + 0.2, location=tuple(centre))
        cone.rotation_mode = "QUATERNION"
        cone.rotation_quaternion = _z_to(direction)
        cutters.append(cone)
    obj = _split_long_edges(_boolean(body, cutters, "UNION"), longest)
    obj.name = "Horns"
    obj.data.shade_smooth()
    return obj


def _z_to(direction):
    """The rotation (w, x, y, z) taking +z to the unit ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    sine, cosine = np.linalg.norm(axis), float(z @ direction)
    if sine < 1e-9:
        return (1.0, 0.0, 0.0, 0.0) if cosine > 0 else (0.0, 1.0, 0.0, 0.0)
    half = math.atan2(sine, cosine) / 2
    return (math.cos(half), *(math.sin(half) * axis / sine))


def slab(size=(2.0, 0.9, 0.12), holes=3, hole_radius=0.22, longest=LONGEST_EDGE):
    box = _primitive(bpy.ops.mesh.primitive_cube_add, size=1.0)
    box.scale = size
    bpy.ops.object.transform_apply(scale=True)
    cutters = []
    for index in range(holes):
        x = size[0] * ((index + 1) / (holes + 1) - 0.5)
        cutters.append(_primitive(bpy.ops.mesh.primitive_cylinder_add, vertices=48,
                                  radius=hole_radius, depth=4 * size[2], location=(x, 0, 0)))
    obj = _split_long_edges(_boolean(box, cutters, "DIFFERENCE"), longest)
    obj.name = "Slab"
    return obj


# The creature's skeleton: (point, skin radius) and edges between the points.
CREATURE_POINTS = [
    ((-0.7, 0, 0.8), 0.22), ((0.0, 0, 0.82), 0.26), ((0.7, 0, 0.85), 0.2),   # spine
    ((1.05, 0, 1.15), 0.13), ((1.35, 0, 1.2), 0.16),                         # neck, head
    ((-1.15, 0, 0.95), 0.06), ((-1.6, 0, 1.15), 0.03),                        # tail
    ((0.6, 0.18, 0.45), 0.08), ((0.62, 0.2, 0.05), 0.06),                     # legs
    ((0.6, -0.18, 0.45), 0.08), ((0.62, -0.2, 0.05), 0.06),
    ((-0.6, 0.18, 0.45), 0.08), ((-0.62, 0.2, 0.05), 0.06),
    ((-0.6, -0.18, 0.45), 0.08), ((-0.62, -0.2, 0.05), 0.06),
]
CREATURE_EDGES = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (2, 7), (7, 8), (2, 9),
                  (9, 10), (0, 11), (11, 12), (0, 13), (13, 14)]


def creature():
    mesh = bpy.data.meshes.new("Creature")
    mesh.from_pydata([p for p, _ in CREATURE_POINTS], CREATURE_EDGES, [])
    obj = _link("Creature", mesh)
    obj.modifiers.new("Skin", "SKIN")          # creates the skin radii layer
    for vertex, (_, radius) in zip(mesh.skin_vertices[0].data, CREATURE_POINTS):
        vertex.radius = (radius, radius)
    mesh.skin_vertices[0].data[1].use_root = True
    obj.modifiers.new("Subdivision", "SUBSURF").levels = 2
    obj = _applied(obj)
    obj.data.shade_smooth()
    return obj


def torus():
    obj = _primitive(bpy.ops.mesh.primitive_torus_add, major_segments=96, minor_segments=32,
                     major_radius=1.0, minor_radius=0.25)
    obj.data.shade_smooth()
    return obj


def rock(strength=0.25):
    sphere = _primitive(bpy.ops.mesh.primitive_ico_sphere_add, subdivisions=6, radius=1.0)
    texture = bpy.data.textures.new("Rock noise", "CLOUDS")
    texture.noise_scale, texture.noise_depth, texture.noise_basis = 0.6, 2, "BLENDER_ORIGINAL"
    displace = sphere.modifiers.new("Displace", "DISPLACE")
    displace.texture, displace.strength, displace.mid_level = texture, strength, 0.5
    obj = _applied(sphere, "Rock")
    obj.data.shade_smooth()
    return obj


# The blob's balls: (centre, radius).
BLOB_BALLS = [((0, 0, 0), 0.8), ((0.7, 0.1, 0.1), 0.6), ((-0.7, -0.1, 0.0), 0.65),
              ((0.2, 0.55, 0.2), 0.5), ((-0.1, -0.5, 0.3), 0.55), ((1.2, 0.0, 0.3), 0.5),
              ((-1.2, 0.2, -0.2), 0.5)]


def blob():
    data = bpy.data.metaballs.new("Blob")
    data.resolution, data.threshold = 0.05, 0.6
    for centre, radius in BLOB_BALLS:
        element = data.elements.new()
        element.co, element.radius = centre, radius
    obj = _link_curve("Blob", data)
    bpy.context.view_layer.update()
    obj = _applied(obj)
    obj.data.shade_smooth()
    return obj


def monkey():
    obj = _primitive(bpy.ops.mesh.primitive_monkey_add, size=2.0)
    obj.modifiers.new("Subdivision", "SUBSURF").levels = 2
    obj = _applied(obj, "Monkey")
    obj.data.shade_smooth()
    return obj


SPLIT = ("text", "horns", "slab")
"""The meshes whose flat faces are split (``LONGEST_EDGE``)."""


def build(name, longest=None):
    """Builds mesh ``name`` in an emptied file, its flat faces split to edges of at most
    ``longest`` (default LONGEST_EDGE; only the SPLIT meshes); its object."""
    _reset()
    if longest is None:
        return globals()[name]()
    if name not in SPLIT:
        raise ValueError(f"'{name}' has no split faces; only {', '.join(SPLIT)} do")
    return globals()[name](longest=longest)


def _canonical(obj):
    """``obj`` with its vertices in the order of their coordinates and its faces in the order
    of their vertices (each starting at its lowest, winding kept): Blender's boolean returns
    the same surface in another order from run to run, and a model names the mesh it was
    trained on by its vertices and faces in order."""
    mesh = obj.data
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    order = np.lexsort((co[:, 2], co[:, 1], co[:, 0]))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    faces = []
    for polygon in mesh.polygons:
        ring = [int(rank[v]) for v in polygon.vertices]
        first = ring.index(min(ring))
        faces.append((tuple(ring[first:] + ring[:first]), polygon.use_smooth))
    faces.sort()
    canonical = bpy.data.meshes.new(mesh.name)
    canonical.from_pydata(co[order].tolist(), [], [ring for ring, _ in faces])
    canonical.polygons.foreach_set("use_smooth", [smooth for _, smooth in faces])
    name = obj.name
    bpy.data.objects.remove(obj)
    return _link(name, canonical)


def write(name, path, longest=None):
    """Writes mesh ``name`` (``build``) as an OBJ file at ``path``, in a canonical order
    (``_canonical``)."""
    obj = _canonical(build(name, longest))
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for other in bpy.data.objects:
        other.select_set(other is obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.wm.obj_export(filepath=str(path), export_selected_objects=True,
                          export_materials=False, export_uv=False, export_normals=False)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=pathlib.Path, required=True,
                        help="folder to write NAME.obj into")
    parser.add_argument("--mesh", action="append", choices=tuple(MESHES),
                        help="only this mesh (repeatable; default every one)")
    parser.add_argument("--longest-edge", type=float, metavar="L",
                        help=f"split flat faces to edges of at most L (default {LONGEST_EDGE}; "
                             f"{', '.join(SPLIT)} only)")
    args = parser.parse_args(argv)
    names = args.mesh or MESHES
    if args.longest_edge is not None:
        if not args.longest_edge > 0:
            parser.error("--longest-edge must be positive")
        if set(names) - set(SPLIT):
            parser.error(f"--longest-edge applies to {', '.join(SPLIT)} only: name them with "
                         "--mesh")
    for name in names:
        write(name, args.out / f"{name}.obj", args.longest_edge)
        print(f"wrote {args.out / f'{name}.obj'} (rig {MESHES[name][0]})")


if __name__ == "__main__":
    from tool_exit import run_and_exit

    run_and_exit(main, sys.argv[1:])
