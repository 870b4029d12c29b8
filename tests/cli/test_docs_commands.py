"""The user docs cannot drift from the product: every batch command that README.md and
docs/cli.md show parses with the real parser and runs, at a small size, through the batch
entry point; docs/cli.md lists exactly the parser's commands and options, with the parser's
defaults; the README stays short.

Commands run in this process (``cli.main``, what ``batch.py`` calls after ``--``) in a
temporary working folder, in document order, so that a command reading what an earlier one
wrote (``train --data data/arm`` after ``dataset --out data/arm``) finds it there. Options
that set a size are lowered (``shrink``); nothing else of a command is changed. The files a
command names as the user's own (``shot.blend``, ``my_model.obj``) are made in that folder.
"""

import argparse
import re
import shlex
import shutil

import pytest
from conftest import REPO

DOCS = ("README.md", "docs/cli.md")
README_WORDS = 1500
# The ways the docs start a batch command; the arguments follow ``--``.
LAUNCHERS = ("blender --background --python vdnif_addon/batch.py --",
             "python vdnif_addon/batch.py --", ".venv/bin/python vdnif_addon/batch.py --")


def documented_commands(name):
    """[(line number, argv after ``--``)] of the batch commands in the doc ``name``: the
    lines of its fenced blocks that start one, and the inline code spans that hold one
    (those with a ``<placeholder>`` only describe the form)."""
    commands, fenced = [], False
    for number, line in enumerate((REPO / name).read_text().splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
            continue
        texts = [line.strip()] if fenced else re.findall(r"`([^`]*batch\.py --[^`]*)`", line)
        for text in texts:
            if "batch.py --" not in text or "<" in text:
                continue
            launcher = next((start for start in LAUNCHERS if text.startswith(start)), None)
            assert launcher is not None, f"{name}:{number}: unknown launcher in {text!r}"
            commands.append((number, shlex.split(text[len(launcher):])))
    return commands


SCENE_COMMANDS = ("capture", "dataset", "references", "train")
IMAGE_COMMANDS = ("references", "render", "evaluate", "side-by-side")
SMALL_TRAINING = {"--rays-per-pose": "256", "--steps": "5", "--batch": "256", "--levels": "2",
                  "--log2-table-size": "10", "--width": "16", "--depth": "1"}


def shrink(argv):
    """``argv`` with every size option at a small value (given or not); a ``--pose-range``
    is scaled with the poses, so that split runs still cover the poses between them."""
    args, command = list(argv), argv[0]

    def given(option):
        return args[args.index(option) + 1] if option in args else None

    def put(option, value):
        if option in args:
            args[args.index(option) + 1] = value
        else:
            args.extend([option, value])

    def at_most(option, value):
        put(option, str(min(int(given(option) or value), value)))

    if command in ("demo", "experiment", "bench") and "--quick" not in args:
        args.append("--quick")
    if command == "experiment":
        at_most("--seeds", 1)
    if command in SCENE_COMMANDS and (command != "train" or "--data" not in args):
        put("--resolution", "8")
        documented = int(given("--poses") or 4)
        at_most("--poses", 4)
        if given("--pose-range"):
            start, stop = (int(part) * int(given("--poses")) // documented
                           for part in given("--pose-range").split(":"))
            put("--pose-range", f"{start}:{stop}")
    if command == "dataset":
        put("--rays-per-pose", SMALL_TRAINING["--rays-per-pose"])
    if command == "train":
        for option, value in SMALL_TRAINING.items():
            put(option, value)
    if command in IMAGE_COMMANDS:
        put("--width", "16")
        put("--height", "16")
    if command in ("references", "evaluate"):
        at_most("--poses", 2)
    if command == "side-by-side":
        put("--poses", "1")
    if command in ("side-by-side", "bench-network"):
        put("--repeats", "1")
    return args


def test_readme_is_a_short_manual():
    words = len((REPO / "README.md").read_text().split())
    assert words <= README_WORDS, f"README.md has {words} words, at most {README_WORDS}"


def test_every_documented_command_parses(core):
    """Each command line of the docs is accepted by the batch parser as written, and the
    shrunk line that the run tests use is too."""
    cli = core("cli")
    for name in DOCS:
        commands = documented_commands(name)
        assert commands, f"{name} shows no batch command"
        for number, argv in commands:
            for line in (argv, shrink(argv)):
                if "--help" in line:
                    with pytest.raises(SystemExit) as leaving:
                        cli.build_parser().parse_args(line)
                    assert leaving.value.code == 0
                    continue
                args = cli.build_parser().parse_args([a for a in line if a != "--debug"])
                assert args.command == argv[0], (name, number, line)


def _cells(row):
    """The cells of a markdown table row; ``\\|`` is a pipe inside a cell."""
    cells = re.split(r"(?<!\\)\|", row.strip().strip("|"))
    return [cell.strip().replace("\\|", "|") for cell in cells]


def option_tables(name="docs/cli.md"):
    """{section heading: {option key: (spec, default, what)}} of the doc's option tables
    (header ``| option | default | what |``), under the heading they follow."""
    tables, heading, rows, fenced = {}, None, None, False
    for line in (REPO / name).read_text().splitlines():
        fenced ^= line.startswith("```")
        if fenced or line.startswith("```"):
            continue
        if line.startswith("#"):
            heading, rows = line.lstrip("#").strip(), None
        elif not line.startswith("|"):
            rows = None
        elif _cells(line) == ["option", "default", "what"]:
            rows = tables.setdefault(heading, {})
        elif rows is not None and not line.startswith("| ---"):
            spec, default, what = _cells(line)
            spec = spec.strip("`")
            key = spec.split()[0]
            assert key not in rows, f"{heading}: {key} listed twice"
            rows[key] = (spec, default, what)
    return tables


def _key(action):
    """An option's name in the tables: its long option, or a positional's choices."""
    if action.option_strings:
        return max(action.option_strings, key=len)
    return "|".join(action.choices)


def _expected_default(action):
    """The default cell the tables must give, or None where the parser's default is computed
    later (None) and the table says in words what it becomes."""
    if action.required or (not action.option_strings and action.default is None):
        return "required"
    if isinstance(action, argparse._StoreTrueAction):
        return "off"
    return None if action.default is None else action.default


def test_cli_md_lists_every_command_and_option_with_its_default(core):
    cli = core("cli")
    parser = cli.build_parser()
    commands = next(action for action in parser._actions
                    if isinstance(action, argparse._SubParsersAction))
    parsers = {"Every command": parser, **commands.choices}
    tables = option_tables()
    assert set(tables) == set(parsers), "docs/cli.md's option tables and the commands differ"
    checked = 0
    for heading, command in parsers.items():
        actions = {_key(action): action for action in command._actions
                   if not isinstance(action, (argparse._HelpAction, argparse._SubParsersAction))}
        rows = tables[heading]
        assert set(rows) == set(actions), (heading, set(rows) ^ set(actions))
        for key, action in actions.items():
            spec, default, what = rows[key]
            assert what, (heading, key)
            if action.choices is not None:
                assert "|".join(action.choices) in f"{spec} {what}", (heading, key, spec)
            expected = _expected_default(action)
            if expected is None:
                assert default and default not in ("off", "required"), (heading, key)
            else:
                shown = expected if isinstance(expected, str) else cli.show_default(expected)
                assert default == shown, (heading, key, default, shown)
            checked += 1
    assert checked > 100


@pytest.fixture
def user_files(core, tmp_path):
    """A working folder with the files the docs name as the user's own: ``shot.blend`` (an
    armature-deformed mesh 'Hero' and a camera 'Camera') and ``my_model.obj``."""
    import bpy

    obj = core("blender.scenes").demo_scene("arm")
    obj.name = "Hero"
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    camera.location = (0.0, -6.0, 0.5)
    camera.rotation_euler = (1.5708, 0.0, 0.0)
    bpy.context.scene.collection.objects.link(camera)
    bpy.context.scene.camera = camera
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"), copy=True)
    shutil.copy(REPO / "assets" / "meshes" / "spot.obj", tmp_path / "my_model.obj")
    return tmp_path


def _absolute_inputs(line, folder):
    """``line`` with its ``--blend`` and ``--mesh`` files made absolute: Blender opens a
    relative path from the folder its process started in, which a test's ``chdir`` does not
    move (a batch process starts in the user's folder, so there the two agree)."""
    return [str(folder / arg) if index and line[index - 1] in ("--blend", "--mesh") else arg
            for index, arg in enumerate(line)]


def _run_documented(name, core, folder, monkeypatch, capsys):
    cli = core("cli")
    monkeypatch.chdir(folder)
    done = set()
    for number, argv in documented_commands(name):
        line = shrink(argv)
        if tuple(line) in done:          # the same command in Blender's and Python's form
            continue
        done.add(tuple(line))
        code = cli.main(_absolute_inputs(line, folder))
        err = capsys.readouterr().err
        assert code == 0, f"{name}:{number}: {shlex.join(line)} exited {code}: {err[-2000:]}"
        assert "vdnif: error" not in err, (name, number, err[-2000:])
    return done


@pytest.mark.slow
def test_readme_commands_run(core, user_files, monkeypatch, capsys):
    done = _run_documented("README.md", core, user_files, monkeypatch, capsys)
    assert (user_files / "models" / "arm.vdnif").is_file()
    assert (user_files / "out" / "arm-frame30" / "render.json").is_file()
    assert (user_files / "out" / "arm-eval.json").is_file()
    assert len(done) >= 4


@pytest.mark.slow
def test_cli_md_commands_run(core, user_files, monkeypatch, capsys):
    _run_documented("docs/cli.md", core, user_files, monkeypatch, capsys)
    assert sorted(path.name for path in (user_files / "data" / "lattice").glob("*.npz"))
    assert (user_files / "models" / "arm.vdnif").is_file()
    assert (user_files / "out" / "hero" / "render.json").is_file()
    assert (user_files / "out" / "demo-quick" / "report.json").is_file()


RESULTS = REPO / "docs" / "results.md"


def test_results_summary_repeats_its_json(core):
    """Each row of the summary tables in docs/results.md (before the experiments' own
    sections) gives its run's medians against the true reference, formatted as the sections
    format them, from the JSON file the row names."""
    import json

    text = core("text")
    summary = RESULTS.read_text().partition("<!-- experiment ")[0]
    rows = [_cells(line) for line in summary.splitlines()
            if line.startswith("| ") and line.rstrip().endswith(".json` |")]
    for scene, model, *figures, source in rows:
        runs = json.loads((RESULTS.parent / source.strip("`")).read_text())["runs"]
        m = runs[f"{scene}/{model}"]["common"]["vs_true"]
        assert figures == [text.percent(m.get("false_negative_rate")),
                           text.percent(m.get("false_positive_rate")),
                           text.value(m["distance_mae"]),
                           text.value(m.get("distance_mae_voxels"), 3),
                           text.value(m["normal_error_deg"], 3),
                           text.value(m.get("albedo_psnr"), 3),
                           text.value(m.get("material_accuracy"), 3)], (scene, model, source)
    assert len(rows) >= 30


def test_every_result_file_is_referenced_and_every_reference_exists(core):
    """docs/results/ holds the files that docs/results.md names, no more (superseded runs
    stay in git's history), and every file it names is there."""
    named = set(re.findall(r"results/([\w.,-]+\.(?:json|png))", RESULTS.read_text()))
    present = {path.name for path in (REPO / "docs" / "results").iterdir()
               if path.name != core("output_rule").OUTPUT_MARK}   # a VDNIF folder's mark
    assert named == present, (sorted(named - present), sorted(present - named))
