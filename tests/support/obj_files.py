"""Reads an OBJ file's geometry with no importer in between: an independent reference for
what Blender's importer and the tools write."""

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
