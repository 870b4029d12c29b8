"""The catalogue of bad inputs, continued (``tests/cli/test_bad_inputs.py`` holds the first part
and the rules): work bounded before it starts (memory, disk, shard rows, frame ranges), a
distributed run that never waits forever, and inputs that were silently wrong. Each case
ends with exit code 1 and one ``vdnif: error:`` line, no traceback, and leaves every file
that existed before byte-identical and no temporary file.

Each row of ``CASES`` is (id, arguments, expected message). Arguments name fixtures in
braces as the first part does, plus {port} (a free TCP port) and {blend:NAME}; leading
``NAME=VALUE`` words set environment variables (``VDNIF_MEMORY_LIMIT`` makes a memory
refusal the same on a machine with more memory free than this one).
"""

import json
import os
import re
import socket
import subprocess
import sys
import time

import pytest
import torch
from bounds_blends import build
from conftest import REPO
from test_bad_inputs import (
    BATCH,
    TIME_LIMIT_S,
    _case_folder,
    _snapshot,
    check_failure,
    trained,  # noqa: F401 - the module's fixture: the arm's dataset and model
)

TRAIN = "train --data {data} --steps 2 --batch 256 --device cpu"
JOIN = "WORLD_SIZE=2 RANK=0 LOCAL_RANK=0 MASTER_ADDR=127.0.0.1 MASTER_PORT={port}"

CASES = [
    # --- frame ranges share the poses' bound
    ("render-frames-a-million", "render --model {model} --out {tmp}/r --frames 1:1048574",
     r"the frame range 1:1048574:1 has 1,048,574 frames, more than the limit 4,096"),
    ("render-frames-beyond-blender", "render --model {model} --out {tmp}/r "
     "--frames 1:99999999999:100000000", r"the frame 99999999999 is outside Blender's frames"),
    # --- memory and disk computed before the work
    ("capture-corners-beyond-memory",
     "VDNIF_MEMORY_LIMIT=8G capture --scene spot --resolution 256 --poses 4096",
     r"capturing 4,096 poses of 'Spot' at resolution 256 \([\d,]+ voxel corners a pose\) "
     r"needs about [\d.]+ GiB of memory, more than the [\d.]+ [GM]iB available here: "
     r"lower --poses "
     r"or --resolution"),
    ("dataset-shard-beyond-limit",
     "dataset --poses 32 --rays-per-pose 4194304 --resolution 8 --out {tmp}/d",
     r"dataset shard 'shard-000000-000032' would hold about [\d,]+ segments, more than the "
     r"limit 268,435,456 \(vdnif_addon/limits.py\): lower --rays-per-pose or --poses"),
    ("dataset-beyond-memory",
     "VDNIF_MEMORY_LIMIT=256M dataset --poses 2 --rays-per-pose 1048576 --resolution 8 "
     "--out {tmp}/d", r"dataset shard 'shard-000000-000002' \([\d,]+ segments\) needs about "
     r"[\d.]+ GiB of memory, more than the 256 MiB available here: lower --rays-per-pose"),
    ("train-scene-dataset-beyond-memory",
     "VDNIF_MEMORY_LIMIT=64M train --scene arm --resolution 8 --poses 2 "
     "--rays-per-pose 262144 --data {tmp}/d --out {tmp}/m.vdnif --steps 2",
     r"dataset shard 'shard-000000-000002' \([\d,]+ segments\) needs about [\d.]+ MiB of "
     r"memory, more than the 64 MiB available here"),
    ("train-dataset-beyond-memory", f"VDNIF_MEMORY_LIMIT=10K {TRAIN} --out {{tmp}}/m.vdnif",
     r"training on the [\d,]+ segments of '.*' needs about [\d.]+ KiB of memory, more than "
     r"the 10 KiB available here: train on a smaller dataset"),
    ("dataset-memory-limit-text", "VDNIF_MEMORY_LIMIT=lots dataset --resolution 8 --poses 2 "
     "--rays-per-pose 64 --out {tmp}/d",
     r"environment variable VDNIF_MEMORY_LIMIT 'lots' is not a number of bytes"),
    # --- distributed training says what it waits for, and for how long
    ("train-second-rank-never-starts", f"{JOIN} {TRAIN} --group-timeout 2 --out {{tmp}}/m.vdnif",
     r"process 0 waited 2 s for the other 1 process\(es\) of WORLD_SIZE=2 to join at "
     r"127.0.0.1:\d+ and they did not: start every rank, or raise --group-timeout"),
    ("train-group-timeout-zero", f"{TRAIN} --group-timeout 0",
     r"--group-timeout 0.0 must be a number in 1..86400"),
    ("train-group-timeout-nan", f"{TRAIN} --group-timeout nan",
     r"--group-timeout nan must be a number in"),
    # --- silently wrong before: refused by name
    ("evaluate-model-of-other-textures", "evaluate --model {bad_model:other_textures} --scene "
     "arm --poses 1 --width 16 --height 16 --json {tmp}/e.json",
     r"was trained on other textures of 'Arm' \(now no image texture in its materials\): "
     r"train it again"),
    ("capture-udim-tile-missing", "capture --blend {blend:udim} --object Plane --resolution 8",
     r"image 'tex.<UDIM>.png' of material 'Tiled' lacks its UDIM tile 1002 \(file "
     r"'.*tex.1002.png'\), which faces of 'Plane' use: it would read as black"),
    ("capture-udim-two-tiles", "capture --blend {blend:udim_both} --object Plane --resolution 8",
     r"image 'tex.<UDIM>.png' of material 'Tiled' is a UDIM image and faces of 'Plane' use its "
     r"tiles 1001, 1002: VDNIF reads one tile \(1001\)"),
]



def _free_port():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def files(trained, tmp_path_factory):  # noqa: F811 - the imported fixture
    data, model = trained
    blends = tmp_path_factory.mktemp("blends")
    built = build(blends)
    from test_bad_inputs_files import _payload, _pickled, _repack

    archive = torch.load(model, weights_only=True)
    inner = _payload(archive)
    inner["metadata"]["grid"]["texture_fingerprint"] = "0" * 64
    other = _repack(archive, _pickled(inner), blends / "other_textures.vdnif")
    inner = _payload(archive)
    inner["metadata"]["grid"].pop("texture_fingerprint", None)   # an untextured mesh has none
    older = _repack(archive, _pickled(inner), blends / "older.vdnif")
    return {"data": data, "model": model,
            "bad_model:other_textures": other, "model:older": older,
            **built}


def _command(text, tmp, files):
    """(argv words, environment) of a case's arguments with its placeholders filled."""
    words = text.split()
    for key, value in files.items():
        words = [word.replace("{" + key + "}", str(value)) for word in words]
    words = [word.replace("{tmp}", str(tmp)).replace("{port}", str(_free_port()))
             for word in words]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    while words and re.fullmatch(r"[A-Z_]+=.*", words[0]):
        name, _, value = words.pop(0).partition("=")
        env[name] = value
    return words, env


@pytest.mark.parametrize("case, text, message", CASES, ids=[case[0] for case in CASES])
def test_bad_input_fails_on_one_line_and_changes_nothing(case, text, message, files,
                                                         tmp_path):
    tmp = _case_folder(tmp_path)
    words, env = _command(text, tmp, files)
    watched = [tmp, *(path for key, path in files.items() if "{" + key + "}" in text)]
    before = _snapshot(*watched)
    start = time.monotonic()
    result = subprocess.run([sys.executable, str(BATCH), "--", *words], capture_output=True,
                            text=True, errors="replace", timeout=TIME_LIMIT_S, cwd=REPO,
                            env=env)
    check_failure(result.returncode, result.stderr, message, time.monotonic() - start)
    after = _snapshot(*watched)
    assert {path: digest for path, digest in after.items() if path in before} == before
    left = [path for path in after if path not in before]
    assert not [path for path in left if os.path.basename(path).startswith(".")], left
    assert not (tmp / "d").exists() and not (tmp / "m.vdnif").exists()


def test_the_catalogue_grew_by_the_cases_of_this_file():
    import test_bad_inputs
    import test_bad_inputs_files

    names = [case[0] for case in CASES]
    assert len(set(names)) == len(names)
    assert not set(names) & {case[0] for case in test_bad_inputs.CASES}
    assert not set(names) & {case[0] for case in test_bad_inputs_files.CASES}


STALLED_RANK = """
import datetime, sys, time
import torch.distributed as dist
dist.init_process_group("gloo", timeout=datetime.timedelta(seconds=60))
print("joined", flush=True)
time.sleep(float(sys.argv[1]))
"""


@pytest.mark.slow
def test_a_rank_that_stops_answering_is_named_within_the_timeout(files, tmp_path):
    """The second rank joins and then never reaches a collective (as one stopped with
    SIGSTOP does): the first stops within its --group-timeout, saying what it waited for."""
    port = _free_port()
    env = dict(os.environ, OMP_NUM_THREADS="1", WORLD_SIZE="2", MASTER_ADDR="127.0.0.1",
               MASTER_PORT=str(port))
    stalled = subprocess.Popen([sys.executable, "-c", STALLED_RANK, "60"],
                               env=dict(env, RANK="1"), stdout=subprocess.PIPE, text=True)
    try:
        start = time.monotonic()
        words, _ = _command(f"{TRAIN} --group-timeout 3 --out {{tmp}}/m.vdnif", tmp_path, files)
        result = subprocess.run([sys.executable, str(BATCH), "--", *words], capture_output=True,
                                text=True, timeout=TIME_LIMIT_S, cwd=REPO,
                                env=dict(env, RANK="0", LOCAL_RANK="0"))
        seconds = time.monotonic() - start
    finally:
        stalled.kill()
        stalled.wait()
    check_failure(result.returncode, result.stderr,
                  r"process 0 waited 3 s for the other 1 process\(es\) of the group to reach "
                  r"the same step .*--group-timeout", seconds)
    assert seconds < 60          # the stalled rank's own wait, and torch's default 30 minutes
    assert not (tmp_path / "m.vdnif").exists()


def test_an_array_of_an_object_that_stays_put_still_captures(files, tmp_path):
    """The control of the refused arrays: the same array before the lattice, its offset
    object still, captures; so does one whose offset object is animated but unread."""
    result = subprocess.run([sys.executable, str(BATCH), "--", "capture", "--blend",
                             str(files["blend:array_still"]), "--object", "Cube",
                             "--resolution", "8", "--poses", "2"], capture_output=True,
                            text=True, timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "captured 'Cube' (lattice)" in result.stdout


@pytest.mark.parametrize("blend", ["blend:array_animated", "blend:array_on_bone"])
def test_an_array_of_a_moving_object_is_followed_by_the_evaluated_surface(files, blend,
                                                                         tmp_path):
    """An array before the rig whose offset object moves with the pose is more than the
    copied modifiers follow (``uncaptured.check_captured`` names it, the test below): the
    capture binds the corners to the evaluated surface instead, and says so."""
    out = tmp_path / "capture.json"
    result = subprocess.run([sys.executable, str(BATCH), "--", "capture", "--blend",
                             str(files[blend]), "--object", "Cube", "--resolution", "8",
                             "--poses", "2", "--json", str(out)], capture_output=True,
                            text=True, timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert json.loads(out.read_text())["corners_follow"] == "evaluated surface"


def test_a_far_loose_vertex_neither_sizes_nor_frames_the_object(files, tmp_path):
    """One loose vertex 1,000 units from a ball of diameter 2: the ball alone sizes and
    frames it (with a warning naming what was left out), and the references compare its
    rays (they compared none and said "n/a" with success)."""
    blend = str(files["blend:loose_vertex"])
    result = subprocess.run([sys.executable, str(BATCH), "--", "references", "--blend", blend,
                             "--object", "Ball", "--resolution", "8", "--poses", "1",
                             "--width", "16", "--height", "16", "--json",
                             str(tmp_path / "r.json")], capture_output=True, text=True,
                            timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert re.search(r"vdnif: warning: 'Ball': left out 1 loose vertex more than 1 x the main "
                     r"body's size \(2\) away", result.stderr), result.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    error = report["embedded_vs_true"]
    assert error["compared_rays"] > 16 * 16 / 8 and error["hit_iou"] > 0.9


def test_a_model_older_than_the_texture_fingerprint_still_evaluates(files, tmp_path):
    """A model file without the texture fingerprint (written before it existed) loads and
    evaluates as before: it is not refused as trained on an edited mesh."""
    result = subprocess.run([sys.executable, str(BATCH), "--", "evaluate", "--model",
                             str(files["model:older"]), "--scene", "arm", "--poses", "1",
                             "--width", "16", "--height", "16"], capture_output=True, text=True,
                            timeout=TIME_LIMIT_S, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "evaluated proposed on 'Arm'" in result.stdout

