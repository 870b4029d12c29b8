"""tools/skinned_character.py --subdivide-after-rig: the dense character keeps its
Subdivision after the armature, so that the network learns the subdivided surface while
the voxel corners follow the cage; a file format that would apply the modifier is refused.
tools/dense_character.py checks its own files by the output rule before any level is built,
trained or timed, and replaces only its own marked files."""

import json
import pathlib
import subprocess
import sys

import pytest
from scene_builders import evaluated_vertices
from tool_errors import load_tool, one_error_line

# The tool imports the core directly, so this file does too (one identity of the core).
from vdnif_addon.blender import capture_scene, deform, poses

TOOLS = pathlib.Path(__file__).resolve().parents[2] / "tools"
character = load_tool(TOOLS / "skinned_character.py")
DENSE = TOOLS / "dense_character.py"
CAGE_TRIANGLES = 5856


def test_the_dense_character_subdivides_after_its_armature():
    import bpy

    body = character.build(subdivide_after_rig=1)
    assert [m.type for m in body.modifiers] == ["ARMATURE", "SUBSURF"]
    assert sum(len(p.vertices) - 2 for p in body.data.polygons) == CAGE_TRIANGLES
    scene = bpy.context.scene
    # both actions play one after the other: the walk (40 frames), then the wave (24)
    assert (scene.frame_start, scene.frame_end) == (1, 64)
    moved = []
    for frame in (1, 20, 50):
        scene.frame_set(frame)
        moved.append(evaluated_vertices(body))
    assert all(abs(pose - moved[0]).max() > 0.05 for pose in moved[1:])
    scene.frame_set(1)
    captured = capture_scene.capture(
        body, 8, poses.PoseSpec(count=2, source="frames"))
    # the rest mesh is the subdivided one; the corners are bound to the cage before it
    assert len(captured.mesh.triangles) == 4 * CAGE_TRIANGLES
    assert captured.corners_follow == "evaluated surface"
    with deform.CornerDeformer(body, captured.grid.corner_positions()) as deformer:
        assert deformer.binding.vertex_count == len(body.data.vertices)


@pytest.mark.parametrize("levels, out, message", [
    ("2", "c.glb", "an exported file would apply the modifier"),
    ("0", "c.blend", "levels of a subdivision are at least 1")])
def test_a_dense_character_it_cannot_write_is_refused(tmp_path, levels, out, message):
    done = subprocess.run([sys.executable, str(TOOLS / "skinned_character.py"),
                           "--subdivide-after-rig", levels, "--out", str(tmp_path / out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and message in done.stderr
    assert not (tmp_path / out).exists()


def test_a_level_file_is_marked_and_replaced_by_the_next_run(tmp_path):
    dense = load_tool(DENSE)
    path = tmp_path / "character-2.json"
    for clean in (False, True):
        dense._write(path, {"level": 2, "clean": clean})
        record = json.loads(path.read_text())
        assert next(iter(record)) == "format" and record["format"] == dense.LEVEL_FORMAT
        assert record["clean"] is clean and "provenance" in record


def test_timing_levels_that_were_never_trained_ends_in_one_error_line(tmp_path):
    line = one_error_line(DENSE, [
        "time", "--levels", "2", "--out", tmp_path, "--json", tmp_path / "timings.json"])
    assert "level 2 has no trained character" in line and "character-2.blend" in line
    assert list(tmp_path.iterdir()) == []
