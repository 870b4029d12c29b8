"""A catalogue of bad inputs across every batch command (a careless or hostile user): each
ends with exit code 1 and one ``vdnif: error:`` line, no traceback, within a time limit, and
leaves every file that existed before byte-identical (and no temporary file behind).

Each row of ``CASES`` is one case: (id, arguments, expected message, how it runs). Arguments
name fixtures in braces: {tmp} (the case's own folder, holding existing.json, file.txt and
existing_dir/), {data} (a dataset folder of the arm at R 8), {model} (a model trained on it),
{bad_data:KIND}, {bad_model:KIND}, {blend:NAME}, {mesh:NAME} (see the builders below).

How it runs: every case runs as users run it, ``batch.py`` in a subprocess (under a second
each when it fails before any work: the batch parser and the option checks import neither
bpy, torch nor Warp, tests/cli/test_batch.py). The fourth column says so; "main"
(``cli.main(argv)`` in this process, what ``batch.py`` calls) remains for a case that needs
to look inside the process.
"""

import hashlib
import json
import os
import pathlib
import re
import shutil
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
from conftest import REPO

BATCH = REPO / "vdnif_addon" / "batch.py"
TIME_LIMIT_S = 90      # per case; the slowest real case (a capture) takes ~10 s loaded
ARM = ["--scene", "arm", "--resolution", "8", "--poses", "2"]
EXISTING = "{tmp}/existing.json"

CASES = [
    # --- arguments: ranges, numbers, choices (capture, dataset, references)
    ("capture-seed-negative", "capture --seed -1", r"--seed -1 must be at least 0", "proc"),
    ("dataset-seed-negative", "dataset --seed -1 --out {tmp}/d", r"--seed -1 must be at least 0",
     "proc"),
    ("capture-seed-huge", "capture --seed 99999999999", r"--seed 99999999999 is more than",
     "proc"),
    ("capture-resolution-zero", "capture --resolution 0", r"resolution 0 is outside 4..256",
     "proc"),
    ("capture-resolution-huge", "capture --resolution 100000", r"resolution 100000 is outside",
     "proc"),
    ("capture-resolution-text", "capture --resolution abc",
     r"--resolution: expected an integer, 'auto' or 'recipe', got 'abc'", "proc"),
    ("capture-poses-zero", "capture --poses 0", r"--poses 0 must be at least 1", "proc"),
    ("capture-poses-huge", "capture --poses 10000000", r"--poses 10000000 is more than", "proc"),
    ("capture-max-angle-nan", "capture --max-angle nan", r"--max-angle nan must be a number in",
     "proc"),
    ("capture-scale-zero", "capture --scale 0", r"object scale 0 must be a finite number", "proc"),
    ("capture-scale-nan", "capture --scale nan", r"object scale nan must be a finite", "proc"),
    ("capture-scale-text", "capture --scale abc", r"object scale 'abc' is not a number", "proc"),
    ("capture-squash-zero", "capture --deform squash:0", r"squash factor 0 must be in", "proc"),
    ("capture-bend-inf", "capture --deform bend:inf", r"deform bend amount inf is not finite",
     "proc"),
    ("capture-deform-kind", "capture --deform wobble:3", r"unknown deform kind 'wobble'", "proc"),
    ("capture-deform-no-value", "capture --deform bend", r"deform 'bend' is not KIND:VALUE",
     "proc"),
    ("capture-scene-unknown", "capture --scene moon", r"invalid choice: 'moon'", "proc"),
    ("capture-two-sources", "capture --scene arm --mesh x.obj", r"not allowed with argument",
     "proc"),
    ("capture-unknown-option", "capture --colour red", r"unrecognized arguments: --colour",
     "proc"),
    ("unknown-command", "frobnicate", r"invalid choice: 'frobnicate'", "proc"),
    ("capture-json-is-folder", "capture --json {tmp}/existing_dir",
     r"--json '.*existing_dir' is a folder", "proc"),
    ("capture-json-under-file", "capture --json {tmp}/file.txt/c.json",
     r"'.*file.txt' is not a folder", "proc"),
    ("capture-mesh-missing", "capture --mesh {tmp}/missing.obj",
     r"mesh file '.*missing.obj' does not exist", "proc"),
    ("capture-blend-missing", "capture --blend {tmp}/missing.blend",
     r"blend file '.*missing.blend' does not exist", "proc"),
    ("dataset-rays-zero", "dataset --out {tmp}/d --rays-per-pose 0",
     r"rays per pose 0 must be at least 1", "proc"),
    ("dataset-rays-huge", "dataset --out {tmp}/d --rays-per-pose 1000000000",
     r"rays per pose 1000000000 is more than", "proc"),
    ("dataset-surface-fraction", "dataset --out {tmp}/d --surface-fraction 1.5",
     r"--surface-fraction 1.5 must be a number in 0..1", "proc"),
    ("dataset-surface-fraction-nan", "dataset --out {tmp}/d --surface-fraction nan",
     r"--surface-fraction nan must be", "proc"),
    ("dataset-out-is-file", "dataset --out {tmp}/file.txt",
     r"--out folder '.*file.txt' exists and is not a folder", "proc"),
    ("dataset-no-out", "dataset --scene arm", r"the following arguments are required: --out",
     "proc"),
    ("dataset-pose-range-text", "dataset {arm} --out {tmp}/d --pose-range x",
     r"pose range 'x' is not of the form A:B", "proc"),
    ("dataset-pose-range-backwards", "dataset {arm} --out {tmp}/d --pose-range 2:1",
     r"pose range 2:1 is outside 0:2", "proc"),
    ("references-width-zero", "references --width 0", r"image width 0 must be at least 1",
     "proc"),
    ("references-height-negative", "references --height -5",
     r"image height -5 must be at least 1", "proc"),
    ("references-224-gib", "references --width 100000 --height 100000",
     r"image width 100000 is more than the limit", "proc"),
    ("references-too-many-pixels", "references --width 16000 --height 16000",
     r"image 16000x16000 has 256,000,000 pixels, more than the limit", "proc"),
    ("references-json-is-folder", "references --json {tmp}/existing_dir",
     r"is a folder, not a file", "proc"),
    # --- scale and coordinates: refused outside the documented range, no NoneType.__format__
    ("references-scale-1e-15", "references {arm} --width 16 --height 16 --scale 1e-15",
     r"'Arm' is 3e-15 units across, outside the supported 1e-05..1e\+09", "proc"),
    ("references-scale-1e15", "references {arm} --width 16 --height 16 --scale 1e15",
     r"'Arm' is 3e\+15 units across, outside the supported", "proc"),
    ("references-failing-run-keeps-json",
     "references {arm} --width 16 --height 16 --scale 1e-20 --json " + EXISTING,
     r"'Arm' is 3e-20 units across", "proc"),
    ("capture-mesh-1e30", "capture --mesh {mesh:huge} --resolution 8",
     r"'huge' is 2e\+30 units across, outside the supported", "proc"),
    ("capture-mesh-no-faces", "capture --mesh {mesh:points} --resolution 8",
     r"mesh file '.*points.obj' holds no faces", "proc"),
    ("capture-mesh-garbage", "capture --mesh {mesh:garbage} --resolution 8",
     r"mesh file .*garbage.obj' holds no faces", "proc"),
    # --- .blend content
    ("capture-lattice-scaled-to-zero", "capture --blend {blend:zero_lattice} --object Cube "
     "--resolution 8 --poses 2", r"lattice 'Lattice' of 'Cube' is scaled to zero", "proc"),
    ("capture-nan-base-colour", "capture --blend {blend:nan_colour} --object Cube "
     "--resolution 8", r"the albedo of 'Bad' has non-finite", "proc"),
    ("capture-blend-no-such-object", "capture --blend {blend:driver} --object Nope",
     r"no object named 'Nope' in the scene", "proc"),
    # --- training data and settings
    ("train-nothing", "train", r"give --data DIR \(a dataset folder\) or scene options", "proc"),
    ("train-data-missing", "train --data {tmp}/missing",
     r"dataset folder '.*missing' does not exist", "proc"),
    ("train-data-empty", "train --data {tmp}/existing_dir", r"holds no shards", "proc"),
    ("train-steps-zero", "train --data {data} --steps 0", r"--steps 0 must be at least 1", "proc"),
    ("train-batch-zero", "train --data {data} --batch 0", r"--batch 0 must be at least 1", "proc"),
    ("train-table-huge", "train --data {data} --log2-table-size 40",
     r"--log2-table-size 40 is more than the limit 24", "proc"),
    ("train-normal-table-huge", "train --data {data} --normal-log2-table-size 40",
     r"--normal-log2-table-size 40 is more than the limit 24", "proc"),
    ("train-growth-nan", "train --data {data} --growth nan", r"--growth nan must be a number",
     "proc"),
    ("train-levels-zero", "train --data {data} --levels 0", r"--levels 0 must be at least 1",
     "proc"),
    ("train-pe-form", "train --data {data} --pe-form sine", r"--pe-form 'sine' must be",
     "proc"),
    ("train-albedo-mode", "train --data {data} --albedo-mode texture",
     r"--albedo-mode 'texture' must be one of 'segment', 'hit'", "proc"),
    ("train-normal-mode", "train --data {data} --normal-mode vertex",
     r"--normal-mode 'vertex' must be one of 'segment', 'hit'", "proc"),
    ("train-out-is-folder", "train --data {data} --out {tmp}/existing_dir",
     r"--out model file '.*existing_dir' is a folder", "proc"),
    ("train-json-is-folder", "train --data {data} --json {tmp}/existing_dir",
     r"--json '.*existing_dir' is a folder", "proc"),
    ("train-header-without-grid", "train --data {bad_data:no_grid} --steps 2",
     r"has no complete grid", "proc"),
    ("train-shard-bad-crc", "train --data {bad_data:bad_crc} --steps 2",
     r"array 'p0' cannot be read: Bad CRC-32", "proc"),
    ("train-shard-string-dtype", "train --data {bad_data:string_dtype} --steps 2",
     r"array 'p0' has dtype <U", "proc"),
    ("train-shard-object-dtype", "train --data {bad_data:object_dtype} --steps 2",
     r"array 'p0' cannot be read: Object arrays cannot be loaded", "proc"),
    ("train-shard-p0-3e38", "train --data {bad_data:huge_p0} --steps 2",
     r"array 'p0' has points outside the grid", "proc"),
    ("train-header-lying-voxel-size", "train --data {bad_data:lying_grid} --steps 2",
     r"voxel size .* differs from the grid's", "proc"),
    ("train-header-lying-extent", "train --data {bad_data:lying_extent} --steps 2",
     r"grid extent .* is not its voxel size", "proc"),
    ("train-header-lying-count", "train --data {bad_data:lying_count} --steps 2",
     r"its header says", "proc"),
    ("train-header-nan-albedo", "train --data {bad_data:nan_albedo} --steps 2",
     r"the albedo table is not all finite", "proc"),
    ("train-shard-short-array", "train --data {bad_data:short_hit} --steps 2",
     r"array 'hit' has \d+ rows, 'p0' has", "proc"),
    # --- models: render and evaluate
    ("render-model-missing", "render --model {tmp}/missing.vdnif {arm} --out {tmp}/r",
     r"model file .*missing.vdnif does not exist", "proc"),
    ("render-model-not-a-model", "render --model {tmp}/file.txt {arm} --out {tmp}/r",
     r"file.txt cannot be read \(corrupt, truncated or not a VDNIF model\)", "proc"),
    ("render-frame-nan", "render --model {model} --out {tmp}/r --frame nan",
     r"--frame nan is not a finite number", "proc"),
    ("render-frame-inf", "render --model {model} --out {tmp}/r --frame inf",
     r"--frame inf is not a finite number", "proc"),
    ("render-width-zero", "render --model {model} --out {tmp}/r --width 0",
     r"image width 0 must be at least 1", "proc"),
    ("render-out-is-file", "render --model {model} --out {tmp}/file.txt",
     r"--out folder '.*file.txt' exists and is not a folder", "proc"),
    ("render-no-out", "render --model {model}", r"the following arguments are required: --out",
     "proc"),
    ("evaluate-model-without-grid", "evaluate --model {bad_model:no_grid} {arm}",
     r"its metadata has no complete grid", "proc"),
    ("evaluate-model-float-resolution", "evaluate --model {bad_model:float_resolution} {arm}",
     r"grid resolution 8.5 is not an integer", "proc"),
    ("evaluate-model-nan-weights", "evaluate --model {bad_model:nan_weights} {arm}",
     r"weights '.*' are not finite numbers", "proc"),
    ("evaluate-model-huge-weights", "evaluate --model {bad_model:huge_weights} {arm}",
     r"weights '.*' are not finite numbers of magnitude at most 1e\+06", "proc"),
    ("evaluate-model-nan-albedo", "evaluate --model {bad_model:nan_albedo} {arm}",
     r"metadata albedo_table has non-finite values", "proc"),
    ("evaluate-wrong-resolution", "evaluate --model {model} --scene arm --resolution 12 "
     "--poses 1 --width 16 --height 16", r"was trained on 'Arm' at resolution 8", "proc"),
    ("evaluate-another-object", "evaluate --model {model} --scene lattice --poses 1 "
     "--width 16 --height 16", r"was trained on 'Arm'", "proc"),
    ("evaluate-pixels", "evaluate --model {model} --width 100000 --height 100000",
     r"image width 100000 is more than the limit", "proc"),
    # --- datasets of another object
    ("dataset-into-another-objects-folder", "dataset --scene lattice --resolution 8 --poses 2 "
     "--rays-per-pose 16 --out {data}", r"holds shards of object 'Arm'", "proc"),
    # --- demo, experiment, bench, side-by-side, bench-network
    ("demo-steps-zero", "demo --quick --steps 0 --out {tmp}/demo",
     r"--steps 0 must be at least 1", "proc"),
    ("demo-steps-negative", "demo --quick --steps -3 --out {tmp}/demo",
     r"--steps -3 must be at least 1", "proc"),
    ("demo-json-is-folder", "demo --quick --out {tmp}/demo --json {tmp}/existing_dir",
     r"is a folder, not a file", "proc"),
    ("demo-out-is-file", "demo --quick --out {tmp}/file.txt", r"exists and is not a folder",
     "proc"),
    ("experiment-unknown", "experiment galaxy", r"invalid choice: 'galaxy'", "proc"),
    ("experiment-results-is-folder", "experiment static --quick --results {tmp}/existing_dir",
     r"--results '.*existing_dir' is a folder", "proc"),
    ("bench-out-is-file", "bench --quick --out {tmp}/file.txt", r"exists and is not a folder",
     "proc"),
    ("bench-presets-is-folder", "bench --quick --presets {tmp}/existing_dir",
     r"--presets '.*' is a folder", "proc"),
    ("bench-work-is-file", "bench --quick --work {tmp}/file.txt",
     r"--work folder '.*file.txt' exists and is not a folder", "proc"),
    ("side-by-side-repeats-zero", "side-by-side --repeats 0", r"--repeats 0 must be at least 1",
     "proc"),
    ("side-by-side-markdown-is-folder", "side-by-side --markdown {tmp}/existing_dir",
     r"--markdown '.*existing_dir' is a folder", "proc"),
    ("side-by-side-width-zero", "side-by-side --width 0", r"image width 0 must be at least 1",
     "proc"),
    ("bench-network-repeats-zero", "bench-network --repeats 0",
     r"--repeats 0 must be at least 1", "proc"),
    ("bench-network-threads-zero", "bench-network --threads 0",
     r"--threads 0 must be at least 1", "proc"),
    ("bench-network-json-is-folder", "bench-network --json {tmp}/existing_dir",
     r"is a folder, not a file", "proc"),
]


# ---- fixtures: a dataset and a model of the arm, and the bad files derived from them


def run_batch(args, timeout=TIME_LIMIT_S):
    return subprocess.run([sys.executable, str(BATCH), "--", *map(str, args)],
                          capture_output=True, text=True, errors="replace", timeout=timeout,
                          cwd=REPO,
                          env=dict(os.environ, OMP_NUM_THREADS="1"))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """(dataset folder, model file) of the arm at R 8: 2 poses, 64 rays, 2 steps."""
    root = tmp_path_factory.mktemp("arm")
    result = run_batch(["train", *ARM, "--rays-per-pose", 64, "--steps", 2, "--batch", 256,
                        "--data", root / "data", "--out", root / "arm.vdnif"], timeout=300)
    assert result.returncode == 0, result.stderr
    return root / "data", root / "arm.vdnif"


def _shard(folder):
    return sorted(pathlib.Path(folder).glob("shard-*.json"))[0].with_suffix("")


def _edit_header(folder, edit):
    path = _shard(folder).with_suffix(".json")
    header = json.loads(path.read_text())
    edit(header)
    path.write_text(json.dumps(header))


def _edit_arrays(folder, edit):
    path = _shard(folder).with_suffix(".npz")
    with np.load(path) as shard:
        arrays = {name: shard[name] for name in shard.files}
    edit(arrays)
    np.savez(path, **arrays)


def _bad_crc(folder):
    """Flips a byte inside the stored data of 'p0.npy' (the zip's CRC no longer matches)."""
    path = _shard(folder).with_suffix(".npz")
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("p0.npy")
    data = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    data[start + info.compress_size // 2] ^= 0xFF
    path.write_bytes(bytes(data))


BAD_DATA = {
    "no_grid": lambda f: _edit_header(f, lambda h: h.pop("grid")),
    "bad_crc": _bad_crc,
    "string_dtype": lambda f: _edit_arrays(f, lambda a: a.update(p0=a["p0"].astype(str))),
    "object_dtype": lambda f: _edit_arrays(f, lambda a: a.update(p0=a["p0"].astype(object))),
    "huge_p0": lambda f: _edit_arrays(f, lambda a: a["p0"].__setitem__(0, 3e38)),
    "lying_grid": lambda f: _edit_header(f, lambda h: h.update(voxel_size=h["voxel_size"] * 2)),
    "lying_extent": lambda f: _edit_header(f, lambda h: h["grid"].update(extent=1e9)),
    "lying_count": lambda f: _edit_header(f, lambda h: h.update(segments=h["segments"] + 5)),
    "nan_albedo": lambda f: _edit_header(f, lambda h: h.update(albedo_table=[["NaN"] * 3])),
    "short_hit": lambda f: _edit_arrays(f, lambda a: a.update(hit=a["hit"][:-1])),
}


def _bad_model(good, target, kind):
    """The model file ``good`` damaged as ``kind`` says, written to ``target`` with a
    matching checksum: its stored metadata edited past ``ModelMetadata``'s checks, or its
    weights."""
    import hashlib
    import io

    import torch

    archive = torch.load(good, weights_only=True)
    inner = torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), weights_only=True)
    meta = inner["metadata"]
    if kind == "no_grid":
        meta.pop("grid")
    elif kind == "float_resolution":
        meta["grid"]["resolution"] = 8.5
    elif kind == "nan_albedo":
        meta["albedo_table"] = [[float("nan")] * 3]
    elif kind in ("nan_weights", "huge_weights"):
        weights = next(iter(inner["state_dict"].values()))
        weights.view(-1)[0] = float("nan") if kind == "nan_weights" else 1e30
    buffer = io.BytesIO()
    torch.save(inner, buffer)
    data = buffer.getvalue()
    archive["payload"] = torch.frombuffer(bytearray(data), dtype=torch.uint8)
    archive["sha256"] = hashlib.sha256(data).hexdigest()
    torch.save(archive, target)
    return target


BLEND_SCRIPT = r"""
import bpy, sys
out = sys.argv[-1]

def fresh():
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    return bpy.context.active_object

cube = fresh()                    # a driver with a Python expression Blender blocks
driver = cube.driver_add("location", 0).driver
driver.type = "SCRIPTED"
driver.expression = "__import__('os').getpid() * 0"
bpy.ops.wm.save_as_mainfile(filepath=out + "/driver.blend")

cube = fresh()                    # a lattice scaled to 0
lattice = bpy.data.objects.new("Lattice", bpy.data.lattices.new("Lattice"))
bpy.context.scene.collection.objects.link(lattice)
lattice.scale = (0.0, 0.0, 0.0)
cube.modifiers.new("Lattice", "LATTICE").object = lattice
bpy.ops.wm.save_as_mainfile(filepath=out + "/zero_lattice.blend")

cube = fresh()                    # a base colour of NaN
material = bpy.data.materials.new("Bad")
material.use_nodes = True
material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (
    float("nan"), 0.5, 0.5, 1.0)
cube.data.materials.append(material)
bpy.ops.wm.save_as_mainfile(filepath=out + "/nan_colour.blend")
"""

MESHES = {
    "huge": "v 0 0 0\nv 1e30 0 0\nv 0 2e30 0\nv 0 0 1e30\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
    "points": "v 0 0 0\nv 1 0 0\nv 0 1 0\n",
    "garbage": "\x00\x01 this is not an OBJ file \xff\n",
}


@pytest.fixture(scope="module")
def files(trained, tmp_path_factory, extension):
    """{placeholder: path} of every fixture file the catalogue names (the spoilt models
    written by the core as the extension holds it, this file's one identity)."""
    data, model = trained
    root = tmp_path_factory.mktemp("bad")
    places = {"data": data, "model": model}
    for kind, spoil in BAD_DATA.items():
        folder = root / f"data-{kind}"
        shutil.copytree(data, folder)
        spoil(folder)
        places[f"bad_data:{kind}"] = folder
    for kind in ("no_grid", "float_resolution", "nan_weights", "huge_weights", "nan_albedo"):
        places[f"bad_model:{kind}"] = _bad_model(model, root / f"{kind}.vdnif", kind)
    blends = root / "blends"
    blends.mkdir()
    subprocess.run([sys.executable, "-c", BLEND_SCRIPT, str(blends)], check=True,
                   capture_output=True, timeout=120)
    for name in ("driver", "zero_lattice", "nan_colour"):
        places[f"blend:{name}"] = blends / f"{name}.blend"
    for name, text in MESHES.items():
        places[f"mesh:{name}"] = root / f"{name}.obj"
        places[f"mesh:{name}"].write_bytes(text.encode("latin-1"))
    return places


def _case_folder(tmp_path):
    (tmp_path / "existing.json").write_text('{"format": "vdnif-report", "keep": true}\n')
    (tmp_path / "file.txt").write_text("keep\n")
    (tmp_path / "existing_dir").mkdir()
    (tmp_path / "existing_dir" / "keep.txt").write_text("keep\n")
    return tmp_path


def _snapshot(*roots):
    """{path: sha256} of every file under ``roots``."""
    found = {}
    for root in roots:
        root = pathlib.Path(root)
        paths = [root] if root.is_file() else [p for p in root.rglob("*") if p.is_file()]
        for path in paths:
            found[str(path)] = hashlib.sha256(path.read_bytes()).hexdigest()
    return found


def _arguments(text, tmp, files):
    args = []
    for word in text.replace("{arm}", " ".join(ARM)).split():
        for key, value in files.items():
            word = word.replace("{" + key + "}", str(value))
        args.append(word.replace("{tmp}", str(tmp)))
    return args


def check_failure(code, stderr, message, seconds):
    lines = [line for line in stderr.splitlines() if line.startswith("vdnif: error:")]
    assert code == 1, stderr
    assert "Traceback" not in stderr, stderr
    assert len(lines) == 1, stderr
    assert re.search(message, lines[0]), (message, lines[0])
    assert "internal error" not in lines[0], lines[0]
    assert seconds < TIME_LIMIT_S


@pytest.mark.parametrize("case, text, message, how", CASES, ids=[c[0] for c in CASES])
def test_bad_input_fails_on_one_line_and_changes_nothing(case, text, message, how, files,
                                                         tmp_path, capfd, empty_scene, core):
    tmp = _case_folder(tmp_path)
    args = _arguments(text, tmp, files)
    watched = [tmp, *(path for key, path in files.items() if "{" + key + "}" in text)]
    before = _snapshot(*watched)
    start = time.monotonic()
    if how == "proc":
        result = run_batch(args)
        code, stderr = result.returncode, result.stderr
    else:
        capfd.readouterr()
        code = core("cli").main(args)
        stderr = capfd.readouterr().err
    check_failure(code, stderr, message, time.monotonic() - start)
    if os.environ.get("VDNIF_CATALOGUE_OUT"):       # the table of messages for a report
        with open(os.environ["VDNIF_CATALOGUE_OUT"], "a") as table:
            line = next(x for x in stderr.splitlines() if x.startswith("vdnif: error:"))
            table.write(json.dumps([case, text, how, line.replace(str(tmp), "{tmp}")]) + "\n")
    after = _snapshot(*watched)
    assert {path: digest for path, digest in after.items() if path in before} == before
    left = [path for path in after if path not in before]
    assert not [p for p in left if ".tmp" in p or ".partial" in p], left


def test_catalogue_is_large_and_covers_every_command():
    assert len(CASES) >= 60 and len({case[0] for case in CASES}) == len(CASES)
    assert all(case[3] == "proc" for case in CASES)     # each as users run it
    commands = {case[1].split()[0] for case in CASES}
    assert commands >= {"capture", "dataset", "references", "train", "render", "evaluate",
                        "demo", "experiment", "bench", "side-by-side", "bench-network"}


def test_a_blend_with_a_blocked_python_driver_does_not_hang_at_exit(files):
    """bpy's exit handlers deadlocked after such a capture printed its results (it ran until
    killed: checked with the old ``sys.exit`` path); batch.py now leaves with ``os._exit``."""
    start = time.monotonic()
    result = run_batch(["capture", "--blend", files["blend:driver"], "--object", "Cube",
                        "--resolution", 8], timeout=60)
    assert result.returncode == 0, result.stderr
    assert "captured 'Cube'" in result.stdout and time.monotonic() - start < 60


def test_capture_json_through_planted_symlinks_overwrites_nothing(tmp_path, empty_scene, core,
                                                                  capfd):
    victim = tmp_path / "victim.json"           # a report VDNIF wrote: the link is replaced
    victim.write_text('{"format": "vdnif-report"}\n')
    target = tmp_path / "c.json"
    for name in ("c.json.tmp", ".c.json.partial"):
        (tmp_path / name).symlink_to(victim)
    target.symlink_to(victim)
    code = core("cli").main(["capture", *ARM, "--json", str(target)])
    assert code == 0, capfd.readouterr().err
    assert victim.read_text() == '{"format": "vdnif-report"}\n' and not target.is_symlink()
    assert json.loads(target.read_text())["object"] == "Arm"


def test_a_mesh_edited_within_its_bounds_is_refused_by_its_old_model(empty_scene, core):
    """The model keeps the rest mesh's fingerprint with its grid."""
    import bpy
    from model_metadata import capture_metadata

    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2)
    obj = bpy.context.active_object
    capture = core("blender.capture_scene").capture
    first = capture(obj, 8)
    metadata = capture_metadata(core, first)
    check = core("inference.evaluation").check_model_fits
    check("m.vdnif", metadata, first.mesh, first.grid)
    inner = min(range(len(obj.data.vertices)), key=lambda i: abs(obj.data.vertices[i].co.z))
    obj.data.vertices[inner].co *= 0.9            # inside the old bounds: the same grid
    obj.data.update()
    edited = capture(obj, 8)
    assert edited.grid.dims.tolist() == first.grid.dims.tolist()
    np.testing.assert_allclose(edited.grid.origin, first.grid.origin)
    with pytest.raises(core("errors").VDNIFError, match="another version of the mesh"):
        check("m.vdnif", metadata, edited.mesh, edited.grid)


def test_debug_shows_the_traceback_and_a_bug_says_it_is_one(core, capfd, monkeypatch):
    cli = core("cli")
    assert cli.main(["capture", "--seed", "-1", "--debug"]) == 1
    err = capfd.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1] == (
        "vdnif: error: --seed -1 must be at least 0")

    def broken(args):
        return 1 / 0

    monkeypatch.setattr(core("cli.pipeline"), "cmd_capture", broken)
    monkeypatch.delenv("VDNIF_DEBUG", raising=False)
    assert cli.main(["capture"]) == 1
    err = capfd.readouterr().err
    assert "Traceback" not in err and err.splitlines() == [
        "vdnif: error: internal error (a bug in VDNIF, please report it): ZeroDivisionError: "
        "division by zero; run again with --debug (or VDNIF_DEBUG=1) for the traceback"]
    monkeypatch.setenv("VDNIF_DEBUG", "1")
    assert cli.main(["capture"]) == 1
    assert "Traceback" in capfd.readouterr().err
