"""The batch commands take how the voxel corners follow the mesh from one choice, measured
once a command (``steps.training_follow``): ``capture`` and ``references`` report it, a
``dataset``'s shards record it and ``train --data`` carries it from them into the model
file. A slab in a tightly fitted lattice follows the evaluated surface; the arm keeps the
copied armature."""

import json

import bpy
import pytest
from thin_lattice import thin_lattice_slab

COPY, SURFACE = "armature copy", "evaluated surface"
SMALL = ["--resolution", "16", "--poses", "2"]
TINY = ["--steps", "3", "--batch", "256", "--log2-table-size", "10", "--device", "cpu"]


@pytest.fixture
def slab(empty_scene, tmp_path):
    """The slab saved in a .blend: ``--blend`` options naming it."""
    thin_lattice_slab()
    path = tmp_path / "slab.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return ["--blend", str(path), "--object", "Slab"]


def run(core, capsys, *argv):
    """Runs one batch command in this process; its stderr."""
    capsys.readouterr()
    assert core("cli").main([str(arg) for arg in argv]) == 0
    return capsys.readouterr().err


def choices(err, follow):
    """How often stderr says a measured choice, and that it chose ``follow``."""
    said = [line for line in err.splitlines() if "corners follow: " in line]
    return len(said), all(f"corners follow: {follow} (embedding error" in line
                          for line in said)


def test_a_thin_lattice_follows_the_surface_in_every_command(slab, core, capsys, tmp_path):
    err = run(core, capsys, "capture", *slab, *SMALL, "--json", tmp_path / "c.json")
    assert json.loads((tmp_path / "c.json").read_text())["corners_follow"] == SURFACE
    assert choices(err, SURFACE) == (1, True)
    err = run(core, capsys, "references", *slab, *SMALL, "--width", "16", "--height", "16",
              "--json", tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["corners_follow"] == SURFACE
    assert choices(err, SURFACE) == (1, True)
    data = tmp_path / "data"
    err = run(core, capsys, "dataset", *slab, *SMALL, "--rays-per-pose", "64", "--out", data)
    assert choices(err, SURFACE) == (1, True)
    [shard] = data.glob("shard-*.json")
    assert json.loads(shard.read_text())["corners_follow"] == SURFACE
    # another command trains on the shards: the way they recorded goes into the model
    err = run(core, capsys, "train", "--data", data, *TINY, "--out", tmp_path / "m.vdnif")
    assert choices(err, SURFACE) == (0, True), "training on shards measures nothing"
    _, metadata = core("model.model_file").load_model(tmp_path / "m.vdnif")
    assert metadata.corners_follow == SURFACE


def test_the_arm_keeps_the_copies(empty_scene, core, capsys, tmp_path):
    arm = ["--scene", "arm"]
    err = run(core, capsys, "capture", *arm, *SMALL, "--json", tmp_path / "c.json")
    assert json.loads((tmp_path / "c.json").read_text())["corners_follow"] == COPY
    assert choices(err, COPY) == (1, True)
    err = run(core, capsys, "references", *arm, *SMALL, "--width", "16", "--height", "16",
              "--json", tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["corners_follow"] == COPY
    assert choices(err, COPY) == (1, True)
