"""tools/dev_meshes.py and tools/dev_mesh_study.py: every development mesh is built as the
closed (or, for Suzanne, open) surface it claims, of bounded size and triangle count, and the
study's table gives the clean-rule verdict of each run file."""

import collections
import json
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from obj_files import read_obj
from tool_errors import load_tool, one_error_line

from vdnif_addon.settings import RIGS

REPO = pathlib.Path(__file__).resolve().parents[2]
TOOLS = REPO / "tools"
MESHES_TOOL, STUDY_TOOL = TOOLS / "dev_meshes.py", TOOLS / "dev_mesh_study.py"

# mesh: (closed, connected pieces, triangles: an exact count or a (low, high) range)
EXPECTED = {
    "text": (True, 1, (5_000, 40_000)),
    # A 64 x 32 UV sphere's lower 16 rings (64 pole triangles and 15 x 64 quads), twice,
    # plus the rim's 64 quads.
    "shell": (True, 1, 2 * (64 + 2 * 15 * 64) + 2 * 64),
    "horns": (True, 1, (5_000, 30_000)),
    "slab": (True, 1, (5_000, 30_000)),
    "creature": (True, 1, (2_000, 20_000)),
    "torus": (True, 1, 2 * 96 * 32),
    "rock": (True, 1, 20 * 4 ** 5),          # an icosahedron subdivided five times
    "blob": (True, 1, (2_000, 30_000)),
    "monkey": (False, 3, (10_000, 30_000)),  # Suzanne's head is open where her eyes sit
}
SPLIT = ("text", "horns", "slab")


def pieces(count, triangles):
    parent = list(range(count))

    def root(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b, c in triangles:
        parent[root(a)] = root(b)
        parent[root(b)] = root(c)
    return len({root(v) for v in np.unique(triangles)})


def signed_volume(vertices, triangles):
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dev-meshes")
    subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(folder)], check=True,
                   capture_output=True, timeout=300)
    return {name: read_obj(folder / f"{name}.obj") for name in EXPECTED}


def test_the_tool_names_each_mesh_once_with_a_procedural_rig():
    meshes = load_tool(STUDY_TOOL).mesh_table()
    assert set(meshes) == set(EXPECTED)
    assert {rig for rig, _ in meshes.values()} == set(RIGS)


@pytest.mark.parametrize("name", EXPECTED)
def test_each_mesh_is_the_surface_it_claims(built, name):
    vertices, triangles = built[name]
    closed, expected_pieces, expected_triangles = EXPECTED[name]
    if isinstance(expected_triangles, int):
        assert len(triangles) == expected_triangles
    else:
        assert expected_triangles[0] <= len(triangles) <= expected_triangles[1]
    assert len(triangles) <= 50_000
    directed = collections.Counter(
        edge for a, b, c in triangles.tolist() for edge in ((a, b), (b, c), (c, a)))
    assert max(directed.values()) == 1, "an edge used twice in one direction"
    open_edges = [edge for edge in directed if edge[::-1] not in directed]
    assert (not open_edges) == closed
    assert pieces(len(vertices), triangles) == expected_pieces
    size = np.ptp(vertices, axis=0)
    assert 1.5 <= size.max() <= 3.5 and size.min() > 0.05 * size.max()
    if closed:      # outward normals
        assert signed_volume(vertices, triangles) > 0
    if name in SPLIT:   # flat faces split: a rig bends them as the voxel grid does
        edges = vertices[triangles] - vertices[np.roll(triangles, 1, axis=1)]
        assert np.linalg.norm(edges, axis=2).max() <= 0.08 + 1e-6


def test_shapes_have_their_stated_measures(built):
    # The shell: an open hemisphere of radius 1, 0.02 thick; the torus 1 and 0.25.
    shell = signed_volume(*built["shell"])
    assert shell == pytest.approx(2 / 3 * math.pi * (1 - 0.98 ** 3), rel=0.02)
    torus = signed_volume(*built["torus"])
    assert torus == pytest.approx(2 * math.pi ** 2 * 1.0 * 0.25 ** 2, rel=0.02)
    # The slab's three holes: its volume is the box's less three cylinders of radius 0.22.
    slab = signed_volume(*built["slab"])
    assert slab == pytest.approx(0.12 * (2.0 * 0.9 - 3 * math.pi * 0.22 ** 2), rel=0.02)
    # The horns reach well past the sphere of radius 0.6 (the farthest about 1.4).
    vertices, _ = built["horns"]
    assert np.linalg.norm(vertices, axis=1).max() > 1.2


def _row(mesh, seed, holes, extras):
    return {"mesh": mesh, "rig": "armature", "seed": seed,
            "test": {"false_negative_rate": holes, "false_positive_rate": extras},
            "training": {"wall_s": 300.0, "steps": 3000},
            "load_average_before": [2.0, 2.0, 2.0], "load_average_after": [3.0, 2.0, 2.0]}


def test_the_table_gives_the_clean_verdict_of_each_run(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    cases = {("shell", 0): (0.004, 0.005, "yes"), ("shell", 1): (0.004, 0.0051, "no"),
             ("text", 0): (0.0051, 0.001, "no"), ("torus", 2): (0.0, 0.0, "yes")}
    for (mesh, seed), (holes, extras, _) in cases.items():
        row = _row(mesh, seed, holes, extras)
        if mesh == "torus":
            row["test_embedded"] = {"false_negative_rate": 0.0012, "false_positive_rate": 0.003}
            row["resolution"] = 48          # what the model trained at (older runs: none)
        (runs / f"{mesh}-seed{seed}.json").write_text(json.dumps(row))
    combined = tmp_path / "combined.json"
    lines = load_tool(STUDY_TOOL).table(runs, combined).splitlines()
    # Rows in the tool's mesh order, then by seed.
    assert [tuple(cell.strip() for cell in line.split("|")[1:4]) for line in lines[2:]] == [
        ("text", "armature", "0"), ("shell", "armature", "0"), ("shell", "armature", "1"),
        ("torus", "armature", "2")]
    verdicts = {(line.split("|")[1].strip(), int(line.split("|")[3])): line.split("|")[7].strip()
                for line in lines[2:]}
    assert verdicts == {key: verdict for key, (_, _, verdict) in cases.items()}
    # The resolution and the model against the embedded reference, where a run recorded them.
    assert [line.split("|")[4].strip() for line in lines[2:]] == [
        "not recorded", "not recorded", "not recorded", "48"]
    assert [line.split("|")[8].strip() for line in lines[2:]] == [
        "not recorded", "not recorded", "not recorded", "0.12 % / 0.3 %"]
    assert len(json.loads(combined.read_text())) == len(cases)


def test_an_empty_run_folder_ends_in_one_error_line(tmp_path):
    line = one_error_line(STUDY_TOOL, ["table", tmp_path, "--json", tmp_path / "x.json"])
    assert "no run files" in line


def test_a_kept_model_is_never_replaced(tmp_path):
    kept = tmp_path / "kept"
    kept.mkdir()
    model = kept / "torus-seed1.vdnif"
    model.write_bytes(b"a model of the user's")
    line = one_error_line(STUDY_TOOL, ["run", "--mesh", "torus", "--seed", "1", "--out",
                                       tmp_path / "runs", "--keep", kept])
    assert "exists" in line and "torus-seed1.vdnif" in line
    assert model.read_bytes() == b"a model of the user's"
    assert not (tmp_path / "runs").exists()


def test_a_foreign_file_in_the_mesh_s_place_is_never_replaced(tmp_path):
    # The study builds the torus and finds another file where it would keep it: it stops
    # before training, naming that file.
    kept = tmp_path / "kept"
    kept.mkdir()
    mesh = kept / "torus.obj"
    mesh.write_text("o the user's torus\n")
    line = one_error_line(STUDY_TOOL, ["run", "--mesh", "torus", "--seed", "1", "--out",
                                       tmp_path / "runs", "--keep", kept])
    assert "exists" in line and "torus.obj" in line
    assert mesh.read_text() == "o the user's torus\n"
    assert sorted(path.name for path in kept.iterdir()) == ["torus.obj"]
    assert not (tmp_path / "runs").exists()


NOTES = '{"the user\'s": "notes"}\n'


def test_no_file_it_did_not_write_is_replaced_and_the_check_comes_first(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    foreign = runs / "torus-seed1.json"
    foreign.write_text(NOTES)
    line = one_error_line(STUDY_TOOL, ["run", "--mesh", "torus", "--seed", "1", "--out",
                                       runs])
    assert "torus-seed1.json" in line and "refusing to replace it" in line
    assert foreign.read_text() == NOTES
    (runs / "torus-seed2.json").write_text(json.dumps(_row("torus", 2, 0.0, 0.0)))
    for command in (["table", runs, "--json", foreign],
                    ["shaded", "--keep", tmp_path, "--mesh", "blob", "--json", foreign]):
        line = one_error_line(STUDY_TOOL, command)
        assert "--json" in line and "refusing to replace it" in line
        assert foreign.read_text() == NOTES


def test_a_foreign_images_folder_is_refused_before_the_training(tmp_path):
    figures = tmp_path / "images" / "torus-seed1"
    figures.mkdir(parents=True)
    (figures / "notes.txt").write_text(NOTES)
    line = one_error_line(STUDY_TOOL, ["run", "--mesh", "torus", "--seed", "1", "--out",
                                       tmp_path / "runs", "--images", tmp_path / "images"])
    assert "--images folder" in line and "did not write" in line
    assert (figures / "notes.txt").read_text() == NOTES
    assert sorted(path.name for path in figures.iterdir()) == ["notes.txt"]
    assert not (tmp_path / "runs").exists()


def test_a_run_file_is_marked_and_the_table_drops_the_mark(tmp_path):
    study = load_tool(STUDY_TOOL)
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "torus-seed0.json").write_text(json.dumps({"format": study.FORMAT,
                                                       **_row("torus", 0, 0.0, 0.0)}))
    combined = tmp_path / "combined.json"
    study.table(runs, combined)
    assert [sorted(row) for row in json.loads(combined.read_text())] == [
        sorted(_row("torus", 0, 0.0, 0.0))]


def test_the_table_writes_nothing_unless_json_names_a_file(tmp_path, capsys):
    """Without --json the table is printed only: the committed results stay as they are."""
    study = load_tool(STUDY_TOOL)
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "torus-seed0.json").write_text(json.dumps(_row("torus", 0, 0.0, 0.0)))
    results = sorted((REPO / "docs" / "results").iterdir())
    before = {path: path.read_bytes() for path in results}
    study.main(["table", str(runs)])
    assert "| torus | armature | 0 |" in capsys.readouterr().out
    assert sorted(path.name for path in tmp_path.iterdir()) == ["runs"]
    assert sorted((REPO / "docs" / "results").iterdir()) == results
    assert all(path.read_bytes() == data for path, data in before.items())


def test_the_shaded_pass_needs_the_kept_model(tmp_path):
    line = one_error_line(STUDY_TOOL, ["shaded", "--keep", tmp_path, "--mesh", "blob",
                                       "--seed", "1", "--json", tmp_path / "shaded.json"])
    assert "blob" in line and "--keep" in line
    assert not (tmp_path / "shaded.json").exists()


def test_two_builds_write_the_same_file(tmp_path, built):
    """Blender's boolean returns the horns' vertices in another order from run to run; the
    tool writes them in one order, so a model trained on one build takes the other."""
    subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(tmp_path), "--mesh",
                    "horns"], check=True, capture_output=True, timeout=300)
    again = read_obj(tmp_path / "horns.obj")
    assert all(np.array_equal(a, b) for a, b in zip(again, built["horns"]))
    # in the order of their coordinates, x first (the OBJ keeps Blender's x)
    assert np.all(np.diff(again[0][:, 0]) >= 0)


def longest_edge(vertices, triangles):
    return max(np.linalg.norm(vertices[triangles[:, k]] - vertices[triangles[:, (k + 1) % 3]],
                              axis=1).max() for k in range(3))


def test_flat_faces_are_split_to_the_longest_edge_asked(tmp_path, built):
    """The split meshes' edges are at most 0.08 (``LONGEST_EDGE``) by default and at most
    ``--longest-edge`` when asked, the shape the same; a mesh without split faces refuses it."""
    for name in SPLIT:
        assert longest_edge(*built[name]) <= 0.08 + 1e-9, name
    subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(tmp_path), "--mesh", "slab",
                    "--longest-edge", "0.16"], check=True, capture_output=True, timeout=300)
    coarse = read_obj(tmp_path / "slab.obj")
    assert 0.08 < longest_edge(*coarse) <= 0.16 + 1e-9
    assert len(coarse[1]) < len(built["slab"][1])
    assert signed_volume(*coarse) == pytest.approx(signed_volume(*built["slab"]), rel=1e-6)
    done = subprocess.run([sys.executable, str(MESHES_TOOL), "--out", str(tmp_path), "--mesh",
                           "torus", "--longest-edge", "0.04"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode != 0 and "--longest-edge" in done.stderr
    assert not (tmp_path / "torus.obj").exists()
