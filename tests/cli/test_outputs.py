"""The output rule (``safe_io.check_replace``): an output replaces only a file of its own kind
that VDNIF wrote; a .blend, a foreign file, a file the same run reads, a device or FIFO (also
through a link) are refused on one line naming the option and the file, and left unchanged.
A run's several files appear together or not at all (``all_or_nothing``), and SIGTERM and
SIGHUP clean up a shard being written as Ctrl+C does.

The table of every output option is derived from the batch parser (an option whose type
carries an ``output_kind``), so a new output option without a row here fails
``test_every_output_option_has_a_row``."""

import hashlib
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys

import pytest
from conftest import REPO
from test_bad_inputs import trained  # noqa: F401 - the arm's dataset and model, trained once

from vdnif_addon import cli
from vdnif_addon.errors import VDNIFError
from vdnif_addon.output_rule import (
    MARKDOWN_MARK,
    OUTPUT_MARK,
    REPORT_FORMAT,
    all_or_nothing,
    check_replace,
    mark_png,
)
from vdnif_addon.safe_io import (
    check_output_file,
    claim_folder,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
)

BATCH = REPO / "vdnif_addon" / "batch.py"
GOLDEN_DATA = REPO / "tests" / "golden" / "arm-dataset"
BLEND_BYTES = b"BLENDER-v405" + bytes(range(256)) * 4     # a .blend's first bytes
FOREIGN = {"json": b'{"user": "settings"}\n', "markdown": b"# my notes\n",
           "model": b"PK\x03\x04 not a model", "folder": b"keep\n"}
SUFFIX = {"json": ".json", "markdown": ".md", "model": ".vdnif"}

# (command, option): (the command's other arguments, the input file option the run reads
# or None when the command reads no file of the user's). {blend} and {model} are input
# files of the run; OUT is where the output option's value goes.
ROWS = {
    ("capture", "--json"): ("capture --blend {blend}", "{blend}"),
    ("dataset", "--out"): ("dataset --blend {blend}", "{blend}"),
    ("references", "--json"): ("references --blend {blend}", "{blend}"),
    ("train", "--data"): ("train --blend {blend}", "{blend}"),
    ("train", "--out"): ("train --blend {blend}", "{blend}"),
    ("train", "--json"): ("train --blend {blend}", "{blend}"),
    ("render", "--out"): ("render --model {model} --blend {blend}", "{model}"),
    ("evaluate", "--out"): ("evaluate --model {model} --blend {blend}", "{model}"),
    ("evaluate", "--json"): ("evaluate --model {model} --blend {blend}", "{model}"),
    ("demo", "--out"): ("demo --quick", None),
    ("demo", "--json"): ("demo --quick --out {tmp}/demo", None),
    ("experiment", "--results"): ("experiment static --quick", None),
    ("bench", "--out"): ("bench --quick", None),
    ("bench", "--presets"): ("bench --quick", None),
    ("bench", "--performance"): ("bench --quick", None),
    ("bench", "--work"): ("bench --quick", None),
    ("side-by-side", "--train"): ("side-by-side --scene arm --model {model}", "{model}"),
    ("side-by-side", "--json"): ("side-by-side --scene arm --model {model}", "{model}"),
    ("side-by-side", "--markdown"): ("side-by-side --scene arm --model {model}", "{model}"),
    ("side-by-side", "--plots"): ("side-by-side --scene arm --model {model}", "{model}"),
    ("side-by-side", "--performance"): ("side-by-side --scene arm --model {model}",
                                        "{model}"),
    ("side-by-side", "--crossover"): ("side-by-side --scene arm --model {model}", "{model}"),
    ("side-by-side", "--save-blend"): ("side-by-side --scene arm --model {model}", "{model}"),
    ("bench-network", "--json"): ("bench-network", None),
}


def output_options():
    """(command, option, kind) of every output option of the batch parser."""
    parser = cli.build_parser()
    commands = next(action for action in parser._actions if action.dest == "command")
    return sorted((name, action.option_strings[0], action.type.output_kind)
                  for name, sub in commands.choices.items() for action in sub._actions
                  if getattr(action.type, "output_kind", None))


def test_every_output_option_has_a_row():
    found = {(command, option) for command, option, _ in output_options()}
    assert found == set(ROWS), (found ^ set(ROWS))
    assert len(found) >= 20


def _snapshot(folder):
    return {str(path.relative_to(folder)): (path.is_symlink(), os.readlink(path)
                                            if path.is_symlink() else
                                            hashlib.sha256(path.read_bytes()).hexdigest()
                                            if path.is_file() else "folder")
            for path in sorted(pathlib.Path(folder).rglob("*"))}


def _no_work(args):
    raise AssertionError(f"'{args.command}' passed its output checks and started its work")


@pytest.fixture
def batch(monkeypatch):
    """Runs ``batch.py -- argv`` in this process with every command's work replaced by a
    failure: a case must end in the checks. Returns (exit code, stderr lines)."""
    real = cli.build_parser

    def parser():
        built = real()
        commands = next(action for action in built._actions if action.dest == "command")
        for sub in commands.choices.values():
            sub.set_defaults(run=_no_work)
        return built

    monkeypatch.setattr(cli, "build_parser", parser)

    def run(argv, capsys):
        code = cli.main([str(word) for word in argv])
        return code, capsys.readouterr().err.strip().splitlines()

    return run


def _inputs(tmp):
    """The run's input files: a .blend and a model file (only their bytes matter here)."""
    (tmp / "input.blend").write_bytes(BLEND_BYTES)
    (tmp / "input.vdnif").write_bytes(b"PK\x03\x04 a model the run reads")
    return {"{blend}": str(tmp / "input.blend"), "{model}": str(tmp / "input.vdnif"),
            "{tmp}": str(tmp)}


def _target(case, kind, tmp, inputs, reads):
    """The value of the output option for ``case``: an existing .blend, a foreign file of
    the option's own suffix, or the run's own input (a folder option: a folder holding
    the .blend / a foreign file / the input)."""
    if kind == "folder":
        folder = tmp / f"{case}-folder"
        folder.mkdir()
        if case == "blend":
            (folder / "shot.blend").write_bytes(BLEND_BYTES)
        elif case == "foreign":
            (folder / "notes.txt").write_bytes(FOREIGN["folder"])
        else:
            shutil.move(inputs[reads], folder / "input")
            os.symlink(folder / "input", inputs[reads])
        return folder
    if case == "blend":
        path = tmp / "shot.blend"
        path.write_bytes(BLEND_BYTES)
    elif case == "foreign":
        path = tmp / f"notes{SUFFIX[kind]}"
        path.write_bytes(FOREIGN[kind])
    else:
        path = pathlib.Path(inputs[reads])
    return path


CASES = [(command, option, kind, case) for command, option, kind in output_options()
         for case in ("blend", "foreign", "input")]


@pytest.mark.parametrize("command, option, kind, case", CASES,
                         ids=[f"{c}-{o[2:]}-{k}" for c, o, _, k in CASES])
def test_an_output_option_refuses_what_vdnif_did_not_write(command, option, kind, case,
                                                            tmp_path, batch, capsys):
    text, reads = ROWS[(command, option)]
    if case == "input" and reads is None:
        pytest.skip(f"'{command}' reads no file of the user's")
    inputs = _inputs(tmp_path)
    target = _target(case, kind, tmp_path, inputs, reads)
    words = text.split()
    for key, value in inputs.items():
        words = [word.replace(key, value) for word in words]
    before = _snapshot(tmp_path)
    code, lines = batch([*words, option, target], capsys)
    assert code == 1 and len(lines) == 1, lines
    assert lines[0].startswith("vdnif: error: ") and option in lines[0], lines
    assert str(target) in lines[0], lines
    assert _snapshot(tmp_path) == before


# --------------------------------------------------------------- the cases found by hand


def test_train_out_a_blend_is_refused(tmp_path, batch, capsys):
    shot = tmp_path / "shot.blend"
    shot.write_bytes(BLEND_BYTES)
    code, lines = batch(["train", "--scene", "arm", "--out", shot], capsys)
    assert code == 1 and lines == [f"vdnif: error: --out model file '{shot}' exists and is "
                                   "not a model file VDNIF wrote: refusing to replace it "
                                   "(remove it or choose another path)"]
    assert shot.read_bytes() == BLEND_BYTES


def test_capture_json_its_own_blend_is_refused(tmp_path, batch, capsys):
    shot = tmp_path / "shot.blend"
    shot.write_bytes(BLEND_BYTES)
    code, lines = batch(["capture", "--blend", shot, "--json", shot], capsys)
    assert code == 1 and lines == [f"vdnif: error: --json '{shot}' is the blend file this "
                                   "run reads: refusing to replace it"]
    assert shot.read_bytes() == BLEND_BYTES


def test_json_and_markdown_at_an_unrelated_file_are_refused(tmp_path, batch, capsys):
    notes = tmp_path / "notes.md"
    notes.write_text("# my notes\n")
    code, lines = batch(["side-by-side", "--scene", "arm", "--markdown", notes], capsys)
    assert code == 1 and "--markdown" in lines[0] and "not a markdown file VDNIF wrote" in \
        lines[0]
    code, lines = batch(["references", "--scene", "arm", "--json", notes], capsys)
    assert code == 1 and "--json" in lines[0] and "not a JSON file VDNIF wrote" in lines[0]
    assert notes.read_text() == "# my notes\n"


def test_train_out_a_shard_of_its_dataset_is_refused(tmp_path, batch, capsys):
    data = tmp_path / "data"
    shutil.copytree(GOLDEN_DATA, data)
    shard = next(data.glob("shard-*.npz"))
    before = _snapshot(tmp_path)
    code, lines = batch(["train", "--data", data, "--out", shard], capsys)
    assert code == 1 and lines == [f"vdnif: error: --out model file '{shard}' is a dataset "
                                   "file this run reads: refusing to replace it"]
    assert _snapshot(tmp_path) == before


def _real_model(path):
    """A real VDNIF model file (a small network) at ``path``."""
    import torch
    from model_metadata import metadata_dict

    from vdnif_addon.model import metadata as metadata_module
    from vdnif_addon.model.metadata import ModelMetadata
    from vdnif_addon.model.model_file import save_model
    from vdnif_addon.model.network import IntersectionNetwork
    from vdnif_addon.settings import Heads, NetworkConfig

    config = NetworkConfig(levels=2, base_resolution=8, log2_table_size=10, width=16,
                           depth=2, heads=Heads(albedo=False, material_count=3))
    torch.manual_seed(0)
    save_model(path, IntersectionNetwork(config), ModelMetadata.from_dict(
        metadata_dict(metadata_module, config), str(path)))
    return path


def test_evaluate_json_its_own_model_is_refused(tmp_path, batch, capsys):
    model = _real_model(tmp_path / "arm.vdnif")
    good = model.read_bytes()
    code, lines = batch(["evaluate", "--model", model, "--scene", "arm", "--json", model],
                        capsys)
    assert code == 1 and lines == [f"vdnif: error: --json '{model}' is the model file this "
                                   "run reads: refusing to replace it"]
    assert model.read_bytes() == good


# --------------------------------------------------------------- what VDNIF may replace


def test_a_model_replaces_a_model_vdnif_wrote_and_nothing_else(tmp_path):
    model = _real_model(tmp_path / "m.vdnif")
    first = model.read_bytes()
    check_output_file(model, "--out", "model")         # a model over a model
    _real_model(model)
    assert model.read_bytes() == first                 # the same network, written again
    with pytest.raises(VDNIFError, match=r"--json '.*m.vdnif' exists and is not a JSON file"):
        check_output_file(model, "--json", "json")     # a report over a model
    with pytest.raises(VDNIFError, match="not a model file VDNIF wrote"):
        write_json_atomic(tmp_path / "x.json", {"a": 1})
        check_output_file(tmp_path / "x.json", "--out", "model")


def test_reports_pngs_and_markdown_vdnif_wrote_are_replaced(tmp_path):
    report = tmp_path / "r.json"
    write_json_atomic(report, {"format": REPORT_FORMAT, "a": 1})
    write_json_atomic(report, {"format": REPORT_FORMAT, "a": 2})
    assert json.loads(report.read_text())["a"] == 2
    whole = tmp_path / "tables.md"
    write_text_atomic(whole, MARKDOWN_MARK + "\n| a |\n", "markdown", "markdown")
    write_text_atomic(whole, MARKDOWN_MARK + "\n| b |\n", "markdown", "markdown")
    sections = tmp_path / "results.md"
    sections.write_text("# Results\n\nhand-written\n\n<!-- static -->\n## s\n"
                        "<!-- end static -->\n")
    check_replace(sections, "--results", "markdown")
    png = tmp_path / "plot.png"
    png.write_bytes(_png())
    with pytest.raises(VDNIFError, match="not a PNG image VDNIF wrote"):
        check_replace(png, "plot")
    mark_png(png)
    check_replace(png, "plot")
    import zlib

    data = png.read_bytes()            # still a valid PNG: every chunk's CRC holds
    at = 8
    while at < len(data):
        size = int.from_bytes(data[at:at + 4], "big")
        body = data[at + 4:at + 8 + size]
        assert zlib.crc32(body) == int.from_bytes(data[at + 8 + size:at + 12 + size], "big")
        at += 12 + size
    assert at == len(data) and data.endswith(b"IEND\xaeB`\x82")


def _png():
    import zlib

    def chunk(kind, body):
        return (len(body).to_bytes(4, "big") + kind + body
                + zlib.crc32(kind + body).to_bytes(4, "big"))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", bytes([0, 0, 0, 1, 0, 0, 0, 1, 8, 0, 0,
                                                          0, 0]))
            + chunk(b"IDAT", zlib.compress(b"\0\0")) + chunk(b"IEND", b""))


def test_an_output_folder_is_new_empty_or_vdnifs_and_marked_at_its_first_file(tmp_path):
    new, empty, foreign = tmp_path / "new", tmp_path / "empty", tmp_path / "foreign"
    empty.mkdir()
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep\n")
    for folder in (new, empty):
        claim_folder(folder, "--out folder")
        assert not (folder / OUTPUT_MARK).exists()          # nothing written yet
        write_bytes_atomic(folder / "passes.exr", b"one")
        assert (folder / OUTPUT_MARK).is_file()
        write_bytes_atomic(folder / "passes.exr", b"two")   # its own file, again
        assert (folder / "passes.exr").read_bytes() == b"two"
        with pytest.raises(VDNIFError, match="not a JSON file VDNIF wrote"):
            write_json_atomic(folder / "passes.exr", {"a": 1})   # not of its kind
    with pytest.raises(VDNIFError, match=r"--out folder '.*foreign' holds files VDNIF did "
                                         r"not write \(such as 'notes.txt'\)"):
        claim_folder(foreign, "--out folder")
    foreign_exr = tmp_path / "elsewhere.exr"          # outside a marked folder: refused
    foreign_exr.write_bytes(b"theirs")
    with pytest.raises(VDNIFError, match="is not an EXR image VDNIF wrote"):
        write_bytes_atomic(foreign_exr, b"ours")
    assert foreign_exr.read_bytes() == b"theirs"


def test_an_empty_file_may_be_replaced(tmp_path):
    """A file of no bytes holds nothing to lose (``mktemp`` made it for the report)."""
    target = tmp_path / "made-by-mktemp"
    target.touch()
    write_json_atomic(target, {"a": 1})
    assert json.loads(target.read_text()) == {"a": 1}


# --------------------------------------------------------------- devices and links


def test_a_device_is_refused_also_through_a_link(tmp_path, batch, capsys):
    link = tmp_path / "out.json"
    link.symlink_to("/dev/null")
    for path in ("/dev/stdout", "/dev/null", "/dev/new.json", link):
        with pytest.raises(VDNIFError, match="a folder of devices, not of files|is a "
                                             "character device, not a regular file"):
            check_output_file(path, "--json", "json")
    code, lines = batch(["capture", "--scene", "arm", "--json", link], capsys)
    assert code == 1 and "--json" in lines[0] and "not a regular file" in lines[0], lines
    assert link.is_symlink() and os.readlink(link) == "/dev/null"
    assert os.path.islink("/dev/stdout") or not os.path.isfile("/dev/stdout")


def test_a_fifo_and_a_link_to_a_foreign_file_are_refused(tmp_path):
    fifo = tmp_path / "r.json"
    os.mkfifo(fifo)
    with pytest.raises(VDNIFError, match="FIFO"):
        write_json_atomic(fifo, {"a": 1})
    victim = tmp_path / "victim.json"
    victim.write_text('{"user": 1}\n')
    link = tmp_path / "c.json"
    link.symlink_to(victim)
    with pytest.raises(VDNIFError, match="not a JSON file VDNIF wrote"):
        write_json_atomic(link, {"a": 1})
    assert link.is_symlink() and victim.read_text() == '{"user": 1}\n'


# --------------------------------------------------------------- several files, or none

FSIZE_SCRIPT = """
import resource, signal, sys
sys.path.insert(0, sys.argv[1])
from vdnif_addon.errors import VDNIFError
from vdnif_addon.output_rule import all_or_nothing
from vdnif_addon.safe_io import write_bytes_atomic
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # a write past the limit fails (EFBIG)
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
folder = sys.argv[2]
try:
    with all_or_nothing():
        write_bytes_atomic(folder + "/normal.png", b"n" * 100)
        write_bytes_atomic(folder + "/albedo.png", b"a" * 100)
        write_bytes_atomic(folder + "/passes.exr", b"e" * 10000)
except VDNIFError as exc:
    print(exc)
    sys.exit(1)
"""


def test_a_file_size_limit_leaves_every_old_file_of_the_set(tmp_path):
    folder = tmp_path / "render"
    folder.mkdir()
    (folder / OUTPUT_MARK).write_text("")
    for name in ("normal.png", "albedo.png", "passes.exr"):
        (folder / name).write_bytes(b"old " + name.encode())
    before = _snapshot(folder)
    result = subprocess.run([sys.executable, "-c", FSIZE_SCRIPT, str(REPO), str(folder)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 1, result.stderr
    assert "passes.exr" in result.stdout and "too large" in result.stdout.lower()
    assert _snapshot(folder) == before          # no new PNG beside the old EXR, no temporary


def test_all_or_nothing_renames_every_file_once_all_are_written(tmp_path):
    with all_or_nothing():
        write_bytes_atomic(tmp_path / "a.exr", b"a")
        write_bytes_atomic(tmp_path / "b.exr", b"b")
        assert sorted(path.name for path in tmp_path.iterdir() if not
                      path.name.startswith(".")) == []
    assert (tmp_path / "a.exr").read_bytes() == b"a" and (tmp_path / "b.exr").read_bytes() == b"b"
    assert sorted(os.listdir(tmp_path)) == ["a.exr", "b.exr"]


# --------------------------------------------------------------- stop signals

SHARD_SCRIPT = """
import sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
from vdnif_addon import cli
from vdnif_addon.training import dataset

def slow_npz(path, arrays):          # a shard write that takes long enough to be stopped
    with open(path, "wb") as file:
        file.write(b"PK" + b"\\0" * 65536)
        file.flush()
        print("writing", flush=True)
        time.sleep(60)

dataset._write_npz = slow_npz
dataset.pack = lambda records, heads: records     # the rows' packing is not under test

def run(args):
    header = dataset._read_header(sorted(dataset.pathlib.Path(sys.argv[3]).glob("*.json"))[0])
    records = {"pose": np.zeros(header.segments, np.int32)}
    dataset.write_shard(sys.argv[2], "shard-000000-000002", records, header)
    return 0

parser = cli.build_parser
def patched():
    built = parser()
    commands = next(a for a in built._actions if a.dest == "command")
    commands.choices["bench-network"].set_defaults(run=run)
    return built
cli.build_parser = patched
sys.exit(cli.main(["bench-network"]))
"""


def _as_from_a_terminal():
    """A child's preexec: the stop signals delivered and handled by default, as for a
    command run from a terminal, whatever this process inherited (a shell starts background
    jobs with SIGINT ignored; a parent may block signals, and a child inherits the mask)."""
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_SETMASK, set())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP", "SIGINT"])
def test_a_stop_signal_during_a_shard_write_leaves_no_partial_shard(name, tmp_path):
    if not hasattr(signal, name):
        pytest.skip(f"{name} does not exist on this platform")
    folder = tmp_path / "data"
    folder.mkdir()
    before = _snapshot(folder)
    child = subprocess.Popen([sys.executable, "-c", SHARD_SCRIPT, str(REPO), str(folder),
                              str(GOLDEN_DATA)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, preexec_fn=_as_from_a_terminal)
    try:
        assert child.stdout.readline().strip() == "writing"
        assert any(path.name.startswith(".shard-") for path in folder.iterdir())
        child.send_signal(getattr(signal, name))
        _, err = child.communicate(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 1, err
    lines = err.strip().splitlines()
    assert lines[-1] in (f"vdnif: error: stopped by {name}", "vdnif: error: interrupted"), err
    left = set(_snapshot(folder))
    assert not [path for path in left if path.startswith(".shard-")], left
    assert not [path for path in left if path.endswith(".npz")], left
    assert set(before) <= set(_snapshot(folder))


def test_the_signal_handlers_come_back_after_a_run(batch, capsys):
    handlers = {name: signal.getsignal(getattr(signal, name)) for name in ("SIGTERM", "SIGHUP")
                if hasattr(signal, name)}
    batch(["capture", "--scene", "arm", "--json", "/dev/null"], capsys)
    assert {name: signal.getsignal(getattr(signal, name)) for name in handlers} == handlers


def _limited(size):
    """A child's preexec: files larger than ``size`` bytes cannot be written (EFBIG, the
    signal that would kill the writer ignored)."""

    def limit():
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    return limit


@pytest.mark.slow
def test_a_render_whose_exr_hits_a_file_size_limit_keeps_its_old_pngs(trained, tmp_path):  # noqa: F811
    """The render writes its PNGs (about 230 bytes at 16x16) before its EXR (about 820):
    under a 512-byte limit the EXR fails, and no new PNG may stand beside the old EXR."""
    _, model = trained
    render = ["render", "--model", model, "--scene", "arm", "--width", 16, "--height", 16]
    first = tmp_path / "first"
    result = _batch_process([*render, "--out", first])
    assert result.returncode == 0, result.stderr
    sizes = {path.name: path.stat().st_size for path in first.iterdir()}
    pngs = [size for name, size in sizes.items() if name.endswith(".png")]
    assert len(pngs) >= 4 and max(pngs) < 512 < sizes["passes.exr"], sizes
    old = tmp_path / "old"                  # a render folder of VDNIF's with older files
    old.mkdir()
    for name in sizes:
        (old / name).write_bytes(b"old " + name.encode())
    before = _snapshot(old)
    result = _batch_process([*render, "--out", old], preexec_fn=_limited(512))
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == (
        f"vdnif: error: cannot write EXR file '{old / 'passes.exr'}': file too large")
    assert _snapshot(old) == before


def _batch_process(args, **kwargs):
    return subprocess.run([sys.executable, str(BATCH), "--", *map(str, args)],
                          capture_output=True, text=True, timeout=300, cwd=REPO,
                          env=dict(os.environ, OMP_NUM_THREADS="1"), **kwargs)


# --------------------------------------------------------------- a model the user loaded

KEEPING_BLEND = """
import sys, bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2)
bpy.context.active_object.name = "Ball"
bpy.context.active_object["vdnif"] = {"model_path": "//ball.vdnif", "model_storage": "FILE"}
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])
"""


@pytest.mark.slow
def test_train_replaces_the_model_a_blend_keeps_only_with_force(tmp_path):
    """A model loaded into the .blend in the panel (file storage: ``//ball.vdnif``) is the
    run's own input model: ``train --out`` over it asks for --force."""
    shot, model = tmp_path / "shot.blend", tmp_path / "ball.vdnif"
    subprocess.run([sys.executable, "-c", KEEPING_BLEND, str(shot)], check=True,
                   capture_output=True, timeout=120)
    _real_model(model)
    kept = model.read_bytes()
    train = ["train", "--blend", shot, "--object", "Ball", "--resolution", 8, "--poses", 2,
             "--rays-per-pose", 64, "--steps", 2, "--batch", 256, "--log2-table-size", 10,
             "--out", model]
    refusal = (f"vdnif: error: --out '{model}' is the model that 'Ball' keeps in its .blend, "
               "which this run reads: refusing to replace it (give --force to replace it)")
    result = _batch_process(train)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == refusal
    assert model.read_bytes() == kept
    # With the resolution suggested (the default), the refusal comes before the suggestion.
    result = _batch_process([word for word in train if word not in ("--resolution", 8)])
    assert result.returncode == 1 and result.stderr.strip().splitlines()[-1] == refusal
    assert "resolution auto" not in result.stderr and model.read_bytes() == kept
    result = _batch_process([*train, "--force"])
    assert result.returncode == 0, result.stderr
    assert model.read_bytes() != kept
