"""Reads an OBJ file's geometry with no importer in between (an independent reference for
what Blender's importer and the tools write), and writes small test meshes."""

import numpy as np


def read_obj(path):
    """(V, 3) vertices and (T, 3) fan-triangulated faces of an OBJ file."""
    vertices, triangles = [], []
    for line in path.read_text().splitlines():
        fields = line.split()
        if fields and fields[0] == "v":
            vertices.append([float(x) for x in fields[1:4]])
        elif fields and fields[0] == "f":
            face = [int(field.split("/")[0]) - 1 for field in fields[1:]]
            triangles += [[face[0], face[i], face[i + 1]] for i in range(1, len(face) - 1)]
    return np.array(vertices), np.array(triangles)


def write_bars(path, pieces):
    """An OBJ of closed bars ``pieces`` [(lo, hi, cuts)]: rings of 4 vertices at ``cuts`` + 1
    places along x, quads between neighbouring rings, a quad at each end."""
    lines, base = [], 1
    for lo, hi, cuts in pieces:
        for ring in range(cuts + 1):
            x = lo[0] + (hi[0] - lo[0]) * ring / cuts
            lines += [f"v {x} {y} {z}" for y, z in ((lo[1], lo[2]), (hi[1], lo[2]),
                                                     (hi[1], hi[2]), (lo[1], hi[2]))]
        for ring in range(cuts):
            a, b = base + 4 * ring, base + 4 * ring + 4
            lines += [f"f {a + k} {a + (k + 1) % 4} {b + (k + 1) % 4} {b + k}" for k in range(4)]
        lines += [f"f {base + 3} {base + 2} {base + 1} {base}",
                  f"f {base + 4 * cuts} {base + 4 * cuts + 1} {base + 4 * cuts + 2} "
                  f"{base + 4 * cuts + 3}"]
        base += 4 * (cuts + 1)
    path.write_text("\n".join(lines) + "\n")
