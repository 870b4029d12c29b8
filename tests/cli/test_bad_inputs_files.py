"""The catalogue of bad inputs, continued (``tests/cli/test_bad_inputs.py`` holds the first part
and the rules): crafted model files and shards, absurd numbers, special files, a full disk,
read-only places. Each case ends with exit code 1 and one ``vdnif: error:`` line, no
traceback, and leaves every file that existed before byte-identical and no temporary file.

Each row of ``CASES`` is (id, arguments, expected message, how it runs). Arguments name
fixtures in braces as the first part does, plus {fifo} (a FIFO), {bad_model:KIND},
{bad_data:KIND}, {blend:NAME} and {ro} (a read-only folder); leading ``NAME=VALUE`` words
set environment variables. How it runs: "proc" runs ``batch.py`` in a subprocess;
"full:N" runs it through ``tests/support/full_disk.py``, as if the disk under {tmp} filled up after
N bytes; "noroot" runs it without root's right to write into read-only folders (dropped
from the capability bounding set when the tests run as root).
"""

import ctypes
import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
import torch
from conftest import REPO
from test_bad_inputs import (
    ARM,
    BATCH,
    TIME_LIMIT_S,
    _case_folder,
    _edit_header,
    _shard,
    _snapshot,
    check_failure,
    trained,  # noqa: F401 - the module's fixture: the arm's dataset and model
)

FULL_DISK = REPO / "tests" / "support" / "full_disk.py"
LONG_NAME = "n" * 252 + ".vdnif"          # 258 bytes: one more than a file system holds
TRAIN = "train --data {data} --steps 2 --batch 256"

CASES = [
    # --- a model path that is not a regular file
    ("render-model-fifo", "render --model {fifo} {arm} --out {tmp}/r",
     r"model file .*model.fifo is not a regular file: it is a FIFO \(named pipe\)", "proc"),
    ("render-model-folder", "render --model {tmp}/existing_dir {arm} --out {tmp}/r",
     r"model file .*existing_dir is not a regular file: it is a folder", "proc"),
    ("render-model-dev-zero", "render --model /dev/zero {arm} --out {tmp}/r",
     r"model file /dev/zero is not a regular file: it is a character device", "proc"),
    # --- crafted model files
    ("evaluate-model-zip-bomb", "evaluate --model {bad_model:bomb} {arm}",
     r"model file .*bomb.vdnif is not a VDNIF model: it would unpack to 67,\d{3},\d{3} "
     r"bytes from [\d,]+ \(VDNIF stores its members uncompressed\)", "proc"),
    ("evaluate-model-nested-100000", "evaluate --model {bad_model:deep} {arm}",
     r"deep.vdnif is damaged: its metadata: nests more than 16 levels of lists", "proc"),
    ("evaluate-model-occlusion-1e30", "evaluate --model {bad_model:occlusion_huge} {arm}",
     r"occlusion_huge.vdnif is damaged: occlusion threshold 1e\+30 must lie in \(0, 1\]",
     "proc"),
    ("evaluate-model-occlusion-nan", "evaluate --model {bad_model:occlusion_nan} {arm}",
     r"occlusion_nan.vdnif is damaged: its metadata thresholds.occlusion has non-finite",
     "proc"),
    ("evaluate-model-train-poses-text", "evaluate --model {bad_model:poses_text} {arm}",
     r"its metadata train_poses is not a list of pose descriptions", "proc"),
    ("evaluate-model-train-pose-frame-text",
     "evaluate --model {bad_model:pose_frame_text} {arm}",
     r"pose_frame_text.vdnif is damaged: pose 0 has no finite frame number", "proc"),
    ("evaluate-model-train-pose-tensor", "evaluate --model {bad_model:pose_tensor} {arm}",
     r"pose figure 'poses\[0\].bones' is not a finite number or plain data", "proc"),
    ("render-model-albedo-empty", "render --model {bad_model:albedo_empty} {arm} --out {tmp}/r",
     r"albedo_empty.vdnif is damaged: its metadata albedo_table has shape \(0,\), not nx3",
     "proc"),
    ("render-model-albedo-short", "render --model {bad_model:albedo_short} {arm} --out {tmp}/r",
     r"albedo_short.vdnif is damaged: its albedo table has 1 rows for 2 materials", "proc"),
    ("render-model-albedo-beyond-float32",
     "render --model {bad_model:albedo_1e300} {arm} --out {tmp}/r",
     r"its metadata albedo_table has values beyond float32's range", "proc"),
    ("evaluate-model-400-digit-steps", "evaluate --model {bad_model:huge_steps} {arm}",
     r"its metadata entry 'training.steps' is not a finite number or plain data", "proc"),
    ("evaluate-model-config-nan", "evaluate --model {bad_model:config_nan} {arm}",
     r"its metadata entry 'training.config.lr' is not a finite number or plain data", "proc"),
    # --- crafted datasets
    ("train-shard-fifo", f"{TRAIN} --data {{bad_data:fifo}}",
     r"dataset shard '.*shard-000000-000002.npz' is not a regular file: it is a FIFO", "proc"),
    ("train-shard-zip-bomb", f"{TRAIN} --data {{bad_data:bomb}}",
     r"is not a VDNIF shard: it would unpack to 67,\d{3},\d{3} bytes from", "proc"),
    ("train-shard-npy-1e12-rows", f"{TRAIN} --data {{bad_data:rows_1e12}}",
     r"array 'p0' claims shape \(1000000000000, 3\) \(12,000,000,000,000 bytes\), its "
     r"member holds", "proc"),
    ("train-shards-overlap", f"{TRAIN} --data {{bad_data:overlap}}",
     r"\(poses 0:2\) and 'shard-000000-000002.json' \(poses 0:2\) overlap", "proc"),
    ("train-manifest-grid-list", f"{TRAIN} --data {{bad_data:manifest_grid}}",
     r"dataset manifest '.*': has no complete grid", "proc"),
    ("train-manifest-pose-range", f"{TRAIN} --data {{bad_data:manifest_pose_range}}",
     r"manifest has unknown entries 'pose_range'", "proc"),
    ("train-header-pose-range-text", f"{TRAIN} --data {{bad_data:pose_range_text}}",
     r"pose range '0:2' is not two integers", "proc"),
    ("train-header-poses-text", f"{TRAIN} --data {{bad_data:poses_text}}",
     r"poses are not a list of pose descriptions", "proc"),
    ("train-header-nested-100000", f"{TRAIN} --data {{bad_data:deep}}",
     r"dataset header '.*' nests too deeply to be read", "proc"),
    ("train-header-nested-20", f"{TRAIN} --data {{bad_data:nested}}",
     r"dataset header '.*': nests more than 16 levels of lists and objects", "proc"),
    ("train-header-albedo-empty", f"{TRAIN} --data {{bad_data:albedo_empty}}",
     r"the albedo table has 0 rows for 1 materials", "proc"),
    ("train-header-albedo-short", f"{TRAIN} --data {{bad_data:albedo_short}}",
     r"the albedo table has 1 rows for 3 materials", "proc"),
    ("train-header-surface-fraction-1e30", f"{TRAIN} --data {{bad_data:fraction_huge}}",
     r"surface fraction 1e\+30 is not a finite number in 0..1", "proc"),
    ("train-header-surface-fraction-nan", f"{TRAIN} --data {{bad_data:fraction_nan}}",
     r"surface fraction nan is not a finite number in 0..1", "proc"),
    ("train-header-400-digit-size", f"{TRAIN} --data {{bad_data:size_digits}}",
     r"object size <an integer of 1329 bits> is not a finite number", "proc"),
    # --- numbers beyond what can be meant
    ("render-frame-1e300", "render --model {model} --out {tmp}/r --frame 1e300",
     r"--frame 1e\+300 is outside Blender's frames -1048574..1048574", "proc"),
    ("render-frame-beyond-blender", "render --model {model} --out {tmp}/r --frame 1048575",
     r"--frame 1\.04858e\+06 is outside Blender's frames", "proc"),
    ("render-frame-before-blender", "render --model {model} --out {tmp}/r --frame=-2e6",
     r"--frame -2e\+06 is outside Blender's frames", "proc"),
    ("bench-network-threads-2147483647", "bench-network --threads 2147483647",
     r"--threads 2147483647 is more than the limit 1,024", "proc"),
    ("bench-network-repeats-huge", "bench-network --repeats 1000000",
     r"--repeats 1000000 is more than the limit 1,000", "proc"),
    ("side-by-side-repeats-huge", "side-by-side --repeats 99999999999",
     r"--repeats 99999999999 is more than the limit", "proc"),
    ("experiment-seeds-zero", "experiment static --quick --seeds 0",
     r"--seeds 0 must be at least 1", "proc"),
    ("train-steps-huge", f"{TRAIN} --steps 1000000000000",
     r"--steps 1000000000000 is more than the limit", "proc"),
    ("references-deform-stretch-1e6", "references {arm} --deform stretch:1e6",
     r"stretch factor 1e\+06 is more than 100", "proc"),
    ("references-deform-squash-1e-6", "references {arm} --deform squash:1e-6",
     r"squash factor 1e-06 is less than 0.01", "proc"),
    ("references-deform-twist-1e300", "references {arm} --deform twist:1e300",
     r"twist 1e\+300 degrees is beyond \+-3600 \(ten turns\)", "proc"),
    ("references-deform-bend-1e5", "references {arm} --deform bend:-1e5",
     r"bend -100000 degrees is beyond \+-3600", "proc"),
    # --- scenes with a transform that is no number
    ("capture-nan-object-location", "capture --blend {blend:nan_location} --object Cube "
     "--resolution 8 --poses 2", r"the object 'Cube' has a location, rotation or scale that "
     r"is not a finite number", "proc"),
    ("capture-infinite-armature-location", "capture --blend {blend:inf_rig} --object Cube "
     "--resolution 8 --poses 2", r"the armature 'Rig' of 'Cube' has a location, rotation or "
     r"scale that is not a finite number", "proc"),
    # --- output places: name length, read-only folders, a full disk, the kernel cache
    ("train-out-name-258-bytes", f"{TRAIN} --out {{tmp}}/{LONG_NAME}",
     r"--out model file '.*' cannot be written: the name 'n{20}\.\.\.' has 258 bytes, more "
     r"than the file system's 255", "proc"),
    ("dataset-out-name-258-bytes", f"dataset {{arm}} --out {{tmp}}/{LONG_NAME}/d",
     r"--out folder '.*' cannot be written: the name 'n{20}\.\.\.' has 258 bytes", "proc"),
    ("train-read-only-data-without-out", "train --data {ro}/data --steps 2 --batch 256",
     r"model file '.*data/proposed.vdnif' cannot be written: folder '.*data' is not "
     r"writable", "noroot"),
    ("dataset-disk-full-at-the-shard", "dataset {arm} --rays-per-pose 64 --out {tmp}/d",
     r"cannot write dataset shard '.*shard-000000-000002.npz': no space left on device",
     "full:5000"),
    ("dataset-disk-full-at-once", "dataset {arm} --rays-per-pose 64 --out {tmp}/d",
     r"cannot write dataset manifest '.*vdnif-dataset.manifest': no space left on device",
     "full:0"),
    ("train-out-disk-full", f"{TRAIN} --out {{tmp}}/m.vdnif",
     r"cannot write model file '.*m.vdnif': no space left on device", "full:50000"),
    ("train-kernel-cache-is-a-file", f"VDNIF_KERNEL_CACHE={{tmp}}/file.txt {TRAIN}",
     r"kernel cache folder '.*file.txt/warp-[^']*' \(from \$VDNIF_KERNEL_CACHE\) cannot be "
     r"created: not a directory", "proc"),
    ("train-kernel-cache-read-only", f"VDNIF_KERNEL_CACHE={{ro}}/cache {TRAIN}",
     r"kernel cache folder '.*/cache/warp-[^']*' \(from \$VDNIF_KERNEL_CACHE\) cannot be "
     r"created: permission denied", "noroot"),
]


# ---- the crafted files


def _payload(archive):
    return torch.load(io.BytesIO(archive["payload"].numpy().tobytes()), weights_only=True)


def _repack(archive, payload, target):
    """``archive`` with the payload bytes ``payload`` and their checksum, saved at
    ``target``."""
    archive = dict(archive, payload=torch.frombuffer(bytearray(payload), dtype=torch.uint8),
                   sha256=hashlib.sha256(payload).hexdigest())
    torch.save(archive, target)
    return target


def _pickled(inner):
    buffer = io.BytesIO()
    torch.save(inner, buffer)
    return buffer.getvalue()


MARK = "NESTED-HERE"


def _nested(payload, depth):
    """The torch archive ``payload`` with the string MARK in its pickle replaced by a list
    nested ``depth`` deep (written as pickle opcodes: pickling it would recurse)."""
    with zipfile.ZipFile(io.BytesIO(payload)) as source:
        members = {info.filename: source.read(info) for info in source.infolist()}
    name = next(name for name in members if name.endswith("data.pkl"))
    mark = b"X" + len(MARK).to_bytes(4, "little") + MARK.encode()   # BINUNICODE opcode
    assert members[name].count(mark) == 1
    members[name] = members[name].replace(mark, b"]" * depth + b"a" * (depth - 1))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as target:
        for member, data in members.items():
            target.writestr(member, data)
    return out.getvalue()


def _bomb(source, target, member_suffix, size=64 << 20):
    """A copy of the zip ``source`` whose member ending in ``member_suffix`` holds ``size``
    zero bytes, deflated to a few tens of KB."""
    with zipfile.ZipFile(source) as archive, zipfile.ZipFile(target, "w") as out:
        for info in archive.infolist():
            if not info.filename.endswith(member_suffix):
                out.writestr(info, archive.read(info))
                continue
            bomb = zipfile.ZipInfo(info.filename)
            bomb.compress_type = zipfile.ZIP_DEFLATED
            with out.open(bomb, "w", force_zip64=True) as member:
                for _ in range(size >> 20):
                    member.write(bytes(1 << 20))
    return target


def _set(path, value):
    def edit(data):
        *parents, last = path
        for key in parents:
            data = data[key]
        data[last] = value
    return edit


BAD_METADATA = {
    "occlusion_huge": _set(["thresholds", "occlusion"], 1e30),
    "occlusion_nan": _set(["thresholds", "occlusion"], float("nan")),
    "poses_text": _set(["train_poses"], "0:2"),
    "pose_frame_text": _set(["train_poses", 0, "frame"], "one"),
    "pose_tensor": _set(["train_poses", 0, "bones"], torch.zeros(3)),
    "albedo_empty": _set(["albedo_table"], []),
    "albedo_short": _set(["network_config", "heads", "material_count"], 2),
    "albedo_1e300": _set(["albedo_table", 0], [1e300, 0.5, 0.5]),
    "huge_steps": _set(["training", "steps"], 10**400),     # beyond a float
    "config_nan": _set(["training", "config", "lr"], float("nan")),
}


def _bad_models(model, root):
    archive = torch.load(model, weights_only=True)
    places = {}
    for kind, edit in BAD_METADATA.items():
        inner = _payload(archive)
        edit(inner["metadata"])
        places[kind] = _repack(archive, _pickled(inner), root / f"{kind}.vdnif")
    inner = _payload(archive)
    inner["metadata"]["train_poses"][0]["bones"] = MARK
    places["deep"] = _repack(archive, _nested(_pickled(inner), 100_000), root / "deep.vdnif")
    places["bomb"] = _bomb(model, root / "bomb.vdnif", "data/0")
    return places


def _forge_rows(folder):
    """Member p0.npy's header claims 10^12 rows; its data stays."""
    path = _shard(folder).with_suffix(".npz")
    with zipfile.ZipFile(path) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f4", "fortran_order": False, "shape": (10**12, 3)})
    member = io.BytesIO(members["p0.npy"])
    assert np.lib.format.read_magic(member) == (1, 0)      # as np.savez writes it
    np.lib.format.read_array_header_1_0(member)
    members["p0.npy"] = header.getvalue() + member.read()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def _replace(folder, suffix, make):
    path = _shard(folder).with_suffix(suffix)
    path.unlink()
    make(path)


def _edit_manifest(folder, change):
    path = folder / "vdnif-dataset.manifest"
    path.write_text(json.dumps(dict(json.loads(path.read_text()), **change)))


def _nest_header(folder, depth):
    def edit(header):
        nested = []
        for _ in range(depth):
            nested = [nested]
        header["poses"][0]["bones"] = nested
    _edit_header(folder, edit)


def _overlap(folder):
    stem = _shard(folder)
    for suffix in (".npz", ".json"):
        shutil.copy(stem.with_suffix(suffix), folder / f"shard-000000-000001{suffix}")


BAD_DATA = {
    "fifo": lambda f: _replace(f, ".npz", os.mkfifo),
    "bomb": lambda f: _bomb(_shard(f).with_suffix(".npz"), f / "bomb.tmp", "hit.npy")
    .replace(_shard(f).with_suffix(".npz")),
    "rows_1e12": _forge_rows,
    "overlap": _overlap,
    "manifest_grid": lambda f: _edit_manifest(f, {"grid": [8, 8, 8]}),
    "manifest_pose_range": lambda f: _edit_manifest(f, {"pose_range": "0:2"}),
    "pose_range_text": lambda f: _edit_header(f, _set(["pose_range"], "0:2")),
    "poses_text": lambda f: _edit_header(f, _set(["poses"], "0:2")),
    "deep": lambda f: _replace(f, ".json", lambda p: p.write_text("[" * 100_000
                                                                  + "]" * 100_000)),
    "nested": lambda f: _nest_header(f, 20),
    "albedo_empty": lambda f: _edit_header(f, _set(["albedo_table"], [])),
    "albedo_short": lambda f: _edit_header(f, lambda h: h["heads"].update(
        material=True, material_count=3, material_slots=[0, 1, 2])),
    "fraction_huge": lambda f: _edit_header(f, _set(["surface_fraction"], 1e30)),
    "fraction_nan": lambda f: _edit_header(f, _set(["surface_fraction"], float("nan"))),
    "size_digits": lambda f: _edit_header(f, _set(["object_size"], 10**400)),
}

BLEND_SCRIPT = r"""
import bpy, sys
out = sys.argv[-1]

def rigged():
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    bone = rig.data.edit_bones.new("Bone")
    bone.head, bone.tail = (0, 0, -1), (0, 0, 1)
    bpy.ops.object.mode_set(mode="OBJECT")
    cube.modifiers.new("Armature", "ARMATURE").object = rig
    cube.vertex_groups.new(name="Bone").add(list(range(8)), 1.0, "REPLACE")
    return cube, rig

cube, rig = rigged()
cube.location = (float("nan"), 0.0, 0.0)
bpy.ops.wm.save_as_mainfile(filepath=out + "/nan_location.blend")
cube, rig = rigged()
rig.location = (0.0, float("inf"), 0.0)   # Blender keeps it as float32's largest number
bpy.ops.wm.save_as_mainfile(filepath=out + "/inf_rig.blend")
cube, rig = rigged()
cube.name = "../../x/Evil"
bpy.ops.wm.save_as_mainfile(filepath=out + "/evil_name.blend")
"""


@pytest.fixture(scope="module")
def files(trained, tmp_path_factory):  # noqa: F811 - the imported fixture
    """{placeholder: path} of every fixture file the cases name."""
    data, model = trained
    root = tmp_path_factory.mktemp("bad-files")
    places = {"data": data, "model": model, "fifo": root / "model.fifo", "ro": root / "ro"}
    os.mkfifo(places["fifo"])
    for kind, path in _bad_models(model, root).items():
        places[f"bad_model:{kind}"] = path
    for kind, spoil in BAD_DATA.items():
        folder = root / f"data-{kind}"
        shutil.copytree(data, folder)
        spoil(folder)
        places[f"bad_data:{kind}"] = folder
    shutil.copytree(data, places["ro"] / "data")
    for folder in (places["ro"] / "data", places["ro"]):
        folder.chmod(0o555)
    blends = root / "blends"
    blends.mkdir()
    subprocess.run([sys.executable, "-c", BLEND_SCRIPT, str(blends)], check=True,
                   capture_output=True, timeout=120)
    for name in ("nan_location", "inf_rig", "evil_name"):
        places[f"blend:{name}"] = blends / f"{name}.blend"
    yield places
    for folder in (places["ro"], places["ro"] / "data"):
        folder.chmod(0o755)


def _without_dac_override():
    """In the child before it runs: drop root's capabilities to write and search any
    folder (CAP_DAC_OVERRIDE 1, CAP_DAC_READ_SEARCH 2) from the bounding set, so that the
    program it runs meets read-only folders as any user does."""
    libc = ctypes.CDLL(None, use_errno=True)
    for capability in (1, 2):
        if libc.prctl(24, capability, 0, 0, 0) != 0:         # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP) failed")


def _command(text, tmp, files):
    """(argv words, environment) of a case's arguments with its placeholders filled."""
    words = text.replace("{arm}", " ".join(ARM)).split()
    for key, value in files.items():
        words = [word.replace("{" + key + "}", str(value)) for word in words]
    words = [word.replace("{tmp}", str(tmp)) for word in words]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    while words and re.fullmatch(r"[A-Z_]+=.*", words[0]):
        name, _, value = words.pop(0).partition("=")
        env[name] = value
    return words, env


def _run(words, env, how, tmp):
    launch = [sys.executable, str(BATCH), "--"]
    preexec = None
    if how.startswith("full:"):
        launch = [sys.executable, str(FULL_DISK), str(tmp), how.partition(":")[2], "--"]
    elif how == "noroot" and os.geteuid() == 0:
        preexec = _without_dac_override
    try:
        return subprocess.run([*launch, *words], capture_output=True, text=True,
                              errors="replace", timeout=TIME_LIMIT_S, cwd=REPO, env=env,
                              preexec_fn=preexec)
    except subprocess.SubprocessError as exc:
        if preexec is None:
            raise
        pytest.skip(f"cannot drop root's write rights here: {exc}")


SLOW = {"train-out-disk-full", "train-kernel-cache-is-a-file", "train-kernel-cache-read-only"}
"""The cases that take over 5 s (they train, or import torch and Warp and read the data)."""


@pytest.mark.parametrize("case, text, message, how", [
    pytest.param(*case, id=case[0], marks=[pytest.mark.slow] if case[0] in SLOW else [])
    for case in CASES])
def test_bad_input_fails_on_one_line_and_changes_nothing(case, text, message, how, files,
                                                         tmp_path):
    tmp = _case_folder(tmp_path)
    words, env = _command(text, tmp, files)
    watched = [tmp, *(path for key, path in files.items()
                      if "{" + key + "}" in text and key != "fifo")]
    before = _snapshot(*watched)
    start = time.monotonic()
    result = _run(words, env, how, tmp)
    check_failure(result.returncode, result.stderr, message, time.monotonic() - start)
    assert "Exception ignored" not in result.stderr, result.stderr
    after = _snapshot(*watched)
    assert {path: digest for path, digest in after.items() if path in before} == before
    left = [path for path in after if path not in before]
    assert not [path for path in left if os.path.basename(path).startswith(".")], left


def test_the_catalogue_grew_by_the_cases_of_this_file():
    import test_bad_inputs

    names = [case[0] for case in CASES]
    assert len(names) >= 30 and len(set(names)) == len(names)
    assert not set(names) & {case[0] for case in test_bad_inputs.CASES}


def test_a_file_name_that_fits_gets_a_temporary_name_that_fits_too(tmp_path):
    """A legal name near 255 bytes: the temporary file beside it (a dot, the name, a dot,
    eight random characters, the suffix) is cut to fit, so the write succeeds; an old
    temporary name of the whole name plus its parts was 270 bytes and failed after the
    work."""
    from vdnif_addon.safe_io import NAME_MAX, atomic_path, write_text_atomic

    for name in ("a" * 249 + ".json", "é" * 122 + ".vdnif", "b" * 200 + "." + "c" * 54):
        target = tmp_path / name
        assert len(os.fsencode(name)) <= NAME_MAX
        with atomic_path(target, "test file") as temporary:
            assert len(os.fsencode(os.path.basename(temporary))) <= NAME_MAX
            assert os.path.dirname(temporary) == str(tmp_path)
        write_text_atomic(target, "kept\n")
        assert target.read_text() == "kept\n"
    assert sorted(os.listdir(tmp_path)) == sorted(
        ["a" * 249 + ".json", "é" * 122 + ".vdnif", "b" * 200 + "." + "c" * 54])


def test_every_count_option_is_bounded(tmp_path):
    """Each integer option of every command, at 10^12 and at -1, is refused by the checks
    that run before any work (``validate_arguments``), on one line naming the option."""
    import argparse

    from vdnif_addon.cli import build_parser
    from vdnif_addon.cli.options import validate_arguments
    from vdnif_addon.errors import VDNIFError

    parser = build_parser()
    commands = next(action for action in parser._actions
                    if isinstance(action, argparse._SubParsersAction)).choices
    checked = 0
    for command, sub in commands.items():
        required = []
        for action in sub._actions:
            if action.required and action.option_strings:
                required += [action.option_strings[0], str(tmp_path / "place")]
            elif action.required:
                required.append(action.choices[0])
        for action in sub._actions:
            if action.type is not int and getattr(action.type, "__name__", "") != (
                    "resolution_option"):
                continue
            option = action.option_strings[0]
            for value in ("1000000000000", "-1"):
                args = parser.parse_args([command, *required, option, value])
                with pytest.raises(VDNIFError) as refused:
                    validate_arguments(args)
                message = str(refused.value)
                assert "\n" not in message and value in message, (command, option, message)
                checked += 1
    assert checked >= 2 * 40


@pytest.mark.slow
def test_an_object_named_like_a_path_is_trained_into_out_by_a_file_name(files, tmp_path):
    """train without --out names its model after the object: an object named
    '../../x/Evil' wrote outside out/ (and created the folder); its name is now one file
    name component in out/."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    result = subprocess.run(
        [sys.executable, str(BATCH), "--", "train", "--blend", str(files["blend:evil_name"]),
         "--object", "../../x/Evil", "--resolution", "8", "--poses", "2", "--rays-per-pose",
         "16", "--steps", "1", "--batch", "64"], capture_output=True, text=True, cwd=work,
        timeout=300, env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert result.returncode == 0, result.stderr
    written = sorted(str(path.relative_to(tmp_path)) for path in tmp_path.rglob("*")
                     if path.is_file())
    # the model and its loss plot beside it, both named by the slug
    assert written == ["a/b/out/_.._x_evil-proposed-training.png",
                       "a/b/out/_.._x_evil-proposed.vdnif"]
