"""tools/separate_parts.py: a mesh's parts are found as its connected pieces, the largest
first; its first file holds bone heat's weights alone, its second the procedural rig's, which
gives a riding part the weights of the largest part's nearest vertex and changes nothing
else; its figures compare the two there."""

import pathlib

import numpy as np
import pytest
from obj_files import write_bars
from tool_errors import load_tool, one_error_line

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "separate_parts.py"


def test_parts_are_the_connected_pieces_largest_first():
    tool = load_tool(TOOL)
    # a fan of 3 triangles (vertices 2-6) and a lone triangle (0, 1, 7) around it
    triangles = np.array([[2, 3, 4], [2, 4, 5], [2, 5, 6], [0, 1, 7]])
    label = tool.parts(8, triangles)
    assert (label[2:7] == 0).all() and (label[[0, 1, 7]] == 1).all()


def test_the_second_file_weights_a_riding_part_as_its_nearest_largest_part_vertex(tmp_path):
    import bpy

    from vdnif_addon.blender.scenes import bone_weights

    tool = load_tool(TOOL)
    mesh = tmp_path / "parts.obj"
    # a bar along the chain (the largest part) and a small box beside its first joint
    write_bars(mesh, [((0, 0, 0), (6, 1, 1), 12), ((1.3, 1.0, 0.3), (1.7, 1.4, 0.7), 1)])
    paths, figures = tool.rig_files(mesh, tmp_path, near=1.0)
    assert len(figures) == 1 and figures[0]["vertices"] == 8
    assert figures[0]["near_vertices"] == 8
    weights = {}
    for path in paths:
        bpy.ops.wm.open_mainfile(filepath=str(path))
        obj = next(o for o in bpy.data.objects if o.type == "MESH")
        raw = bone_weights(obj)
        weights[path.name] = raw / raw.sum(1, keepdims=True)
        vertices = np.array([v.co for v in obj.data.vertices])
        label = tool.parts(len(vertices), tool.mesh_triangles(obj))
    rigged, follow = weights["bone-heat.blend"], weights["riders-follow.blend"]
    largest, other = np.flatnonzero(label == 0), np.flatnonzero(label != 0)
    assert len(other) == 8
    gaps = np.linalg.norm(vertices[other, None] - vertices[None, largest], axis=2)
    index = gaps.argmin(1)
    np.testing.assert_allclose(follow[other], rigged[largest[index]], atol=1e-6)
    np.testing.assert_allclose(follow[largest], rigged[largest], atol=1e-6)
    # the figure is the same difference, before the parts were reweighted
    difference = np.abs(rigged[other] - rigged[largest[index]]).sum(1)
    assert figures[0]["weight_difference_median"] == pytest.approx(np.median(difference))
    assert difference.max() > 0.01     # bone heat weighted the box otherwise: the test can fail


def test_bad_options_are_refused_in_one_line_before_any_work(tmp_path):
    line = one_error_line(TOOL, ["--mesh", "torus", "--json", tmp_path / "x.json"])
    assert "'torus'" in line and "lattice" in line
    assert not (tmp_path / "x.json").exists()
    line = one_error_line(TOOL, ["--resolution", "1000", "--json", tmp_path / "x.json"])
    assert "resolution 1000" in line and not (tmp_path / "x.json").exists()
    line = one_error_line(TOOL, ["--near", "0", "--json", tmp_path / "x.json"])
    assert "--near" in line and not (tmp_path / "x.json").exists()
