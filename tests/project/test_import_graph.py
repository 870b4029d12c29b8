"""The layering of the sources, read from their import statements (every one, those inside
functions too): no import cycle; the studies and the batch commands sit on top, so nothing
below them imports them; bpy only in the Blender layers; no module past the size tripwire.

Layers (README, Developing), lowest first: the foundations (``vdnif_addon/*.py``: errors, limits,
settings, ...), then the pipeline's stages ``geometry/`` < ``kernels/`` < ``tracing/`` <
``model/`` < ``training/`` < ``inference/`` < ``posed/`` (a posed object, without Blender),
then ``blender/`` (the bpy adapters and the steps that drive them) < ``studies/`` < ``cli/``
(and ``batch.py``), with the extension's root modules
(``__init__``, ``preferences``, ``properties``, ``storage``, ``viewer``, ``operators/``,
``panels/``) beside ``cli/`` above the core. A module imports its own layer or lower ones.
"""

import ast
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
CORE = "vdnif_addon"
ROOT_FOLDERS = ("operators", "panels")        # the extension's root modules, with its *.py
BLENDER_MODULES = {"bpy", "bpy_extras", "mathutils", "bmesh"}
# Where bpy may be imported: the Blender layers of the core and the extension's glue.
BPY_ALLOWED = (f"{CORE}.blender", f"{CORE}.cli", f"{CORE}.studies", "", "preferences",
               "properties", "storage", "viewer", "operators", "panels")
TOP_LAYERS = (f"{CORE}.cli", f"{CORE}.studies")
# The core's layers, lowest first; the foundations are vdnif_addon's own modules.
STAGES = ("geometry", "kernels", "tracing", "model", "training", "inference", "posed",
          "blender", "studies", "cli")
# Modules of blender/ that reach no bpy import, each with why it still belongs there: every
# other module of blender/ imports bpy, or a module of blender/ that does.
BLENDER_WITHOUT_BPY = {
    f"{CORE}.blender.lights": "reads the scene's light objects (Blender data, read by "
                              "attribute: the module needs a live scene, not bpy's import)",
}
# A module holds one idea, however long: it is split where it holds two ideas, never to
# fit a size. Past this many lines a module is worth a look for a second idea inside it; the
# number is a tripwire, not a target.
TRIPWIRE_LINES = 800


def source_files(repo):
    """{dotted module name: path} of the extension root's and vdnif_addon's .py files; a
    package is named by its ``__init__`` (the extension root's is "")."""
    paths = [*repo.glob("*.py"), *(repo / CORE).rglob("*.py"),
             *(path for folder in ROOT_FOLDERS for path in (repo / folder).rglob("*.py"))]
    files = {}
    for path in paths:
        parts = path.relative_to(repo).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        files[".".join(parts)] = path
    return files


def _join(base, name):
    return f"{base}.{name}" if base and name else base or name


def _is_type_checking(test):
    """``TYPE_CHECKING`` or ``typing.TYPE_CHECKING``."""
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports(name, path, known):
    """(modules of ``known`` that ``name`` imports, top-level names of the other imports).
    ``from P import x`` is an edge to P.x where that is a module, else to P: importing a
    package counts as an edge to its ``__init__`` only."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    edges, external = set(), set()

    def add(target):
        while target not in known and "." in target:    # a name inside a module
            target = target.rpartition(".")[0]
        if target in known and target != name:
            edges.add(target)

    tree = ast.parse(path.read_text(), str(path))
    # Imports under ``if TYPE_CHECKING:`` never run (annotations only): no edge.
    type_only = {id(inner) for node in ast.walk(tree)
                 if isinstance(node, ast.If) and _is_type_checking(node.test)
                 for statement in node.body for inner in ast.walk(statement)}
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == CORE:
                    add(alias.name)
                else:
                    external.add(alias.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package
                for _ in range(node.level - 1):
                    base = base.rpartition(".")[0]
                target = _join(base, node.module or "")
            elif (node.module or "").split(".")[0] == CORE:
                target = node.module
            else:
                external.add(node.module.split(".")[0])
                continue
            for alias in node.names:
                full = _join(target, alias.name)
                add(full if full in known else target)
    return edges, external


def import_graph(repo):
    files = source_files(repo)
    known = set(files)
    graph, external = {}, {}
    for name, path in files.items():
        graph[name], external[name] = imports(name, path, known)
    return files, graph, external


def cycles(graph):
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in graph.get(node, ()):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def within(name, layers):
    """Whether module ``name`` is one of ``layers`` or inside one of them."""
    return any(name == layer or (layer and name.startswith(layer + ".")) for layer in layers)


def layering_problems(graph, external):
    """Every import that breaks the layering, as one line each."""
    problems = []
    for name, targets in sorted(graph.items()):
        for target in sorted(targets):
            if within(target, TOP_LAYERS) and not within(name, TOP_LAYERS):
                if not (name == f"{CORE}.batch" and within(target, (f"{CORE}.cli",))):
                    problems.append(f"{name or '(extension root)'} imports {target}, which "
                                    "sits above it")
            if within(target, (f"{CORE}.cli",)) and within(name, (f"{CORE}.studies",)):
                problems.append(f"{name} imports {target}: studies sit below the commands")
        for module in sorted(external[name] & BLENDER_MODULES):
            if not within(name, BPY_ALLOWED):
                problems.append(f"{name} imports {module} outside the Blender layers")
    return problems


def stage(name):
    """The index of module ``name``'s layer in STAGES (-1: a foundation of vdnif_addon), or
    None outside vdnif_addon (the extension's root modules and glue)."""
    if name == CORE or name == f"{CORE}.batch":
        return len(STAGES) if name == f"{CORE}.batch" else -1
    if not name.startswith(CORE + "."):
        return None
    first = name.split(".")[1]
    return STAGES.index(first) if first in STAGES else -1


def stage_problems(graph):
    """Every import of vdnif_addon that reaches a higher layer, one line each."""
    problems = []
    for name, targets in sorted(graph.items()):
        mine = stage(name)
        for target in sorted(targets):
            theirs = stage(target)
            if mine is not None and theirs is not None and theirs > mine:
                problems.append(f"{name} imports {target}, a later layer")
    return problems


@pytest.fixture(scope="module")
def graph():
    return import_graph(REPO)


def test_the_graph_is_read(graph):
    """The parser sees the modules and the imports it should (a guard on the test itself)."""
    files, edges, external = graph
    assert len(files) > 60 and "" in files and "viewer" in files
    assert {f"{CORE}.cli.pipeline", f"{CORE}.cli.options"} <= edges[f"{CORE}.cli"] | edges[
        f"{CORE}.cli.pipeline"]
    assert f"{CORE}.cli" in edges[f"{CORE}.batch"]                     # absolute, in a function
    assert f"{CORE}.blender.capture_scene" in edges[f"{CORE}.cli.pipeline"]  # relative, in a fn
    assert f"{CORE}.text" in edges["operators.passes"]             # from the root, two dots
    assert "bpy" in external["viewer"] and "torch" in external[f"{CORE}.model.network"]


def test_no_import_cycle(graph):
    _, edges, _ = graph
    assert cycles(edges) == []


def test_nothing_below_imports_the_commands_or_studies_and_bpy_stays_in_blender(graph):
    _, edges, external = graph
    assert stage_problems({f"{CORE}.geometry.g": {f"{CORE}.kernels.k"},
                           f"{CORE}.kernels.k": {f"{CORE}.geometry.g", f"{CORE}.errors"},
                           f"{CORE}.errors": set()}) == [
        f"{CORE}.geometry.g imports {CORE}.kernels.k, a later layer"]
    assert layering_problems(edges, external) == []


def test_each_stage_imports_only_itself_and_earlier_stages(graph):
    _, edges, _ = graph
    assert stage_problems(edges) == []


def test_no_type_only_import_points_to_a_later_layer():
    """A type-only import is no edge of the graph above, but a kernel that names a tracing
    type still reads as a circle: none reaches a later layer."""
    files = source_files(REPO)
    known = set(files)
    problems = []
    for name, path in sorted(files.items()):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and _is_type_checking(node.test):
                wrapper = ast.Module(body=node.body, type_ignores=[])
                for inner in ast.walk(wrapper):
                    if isinstance(inner, ast.ImportFrom) and inner.level:
                        base = name if path.name == "__init__.py" else name.rpartition(".")[0]
                        for _ in range(inner.level - 1):
                            base = base.rpartition(".")[0]
                        target = _join(base, inner.module or "")
                        while target not in known and "." in target:
                            target = target.rpartition(".")[0]
                        mine, theirs = stage(name), stage(target)
                        if mine is not None and theirs is not None and theirs > mine:
                            problems.append(f"{name} names {target}, a later layer")
    assert problems == []


def reaches_bpy(edges, external):
    """Modules of blender/ that import bpy (or mathutils, bmesh) or reach one of blender/'s
    that does, through imports inside blender/."""
    layer = f"{CORE}.blender"
    reached = {name for name in edges if within(name, (layer,))
               and external[name] & BLENDER_MODULES}
    grown = True
    while grown:
        more = {name for name, targets in edges.items() if within(name, (layer,))
                and name not in reached and targets & reached}
        reached |= more
        grown = bool(more)
    return reached


def test_every_module_of_blender_needs_bpy(graph):
    """blender/ holds the bpy adapters and what drives them; the rest of the posed pipeline
    lives in posed/, which runs without Blender. A module of blender/ that reaches no bpy is
    one of the listed exceptions, each with its reason."""
    _, edges, external = graph
    layer = f"{CORE}.blender"
    modules = {name for name in edges if within(name, (layer,)) and name != layer}
    assert len(modules) > 8                        # the walk finds blender/
    without = modules - reaches_bpy(edges, external)
    assert without == set(BLENDER_WITHOUT_BPY), (
        "modules of blender/ that need no bpy belong in posed/ (or list them with a reason)")
    assert not any(within(name, (f"{CORE}.posed",)) and external[name] & BLENDER_MODULES
                   for name in edges)


def test_no_module_of_vdnif_addon_past_the_size_tripwire():
    """The rule is one idea per module, however long (``TRIPWIRE_LINES``); a module that
    grows past the tripwire is split where it holds two ideas, or the tripwire is raised
    with the reason, never cut in two by size."""
    sizes = {path.relative_to(REPO).as_posix(): len(path.read_text().splitlines())
             for path in (REPO / CORE).rglob("*.py")}
    assert len(sizes) > 60                         # the walk finds the modules
    over = {path: lines for path, lines in sizes.items() if lines > TRIPWIRE_LINES}
    assert over == {}, (f"over {TRIPWIRE_LINES} lines: does one of them hold two ideas? "
                        "split it where they part, not by size")


def test_the_checks_find_what_they_look_for(tmp_path):
    """On a small tree with a cycle, a core module importing a study and the CLI, and bpy in
    the core, every check reports it."""
    core = tmp_path / CORE
    for folder in ("blender", "studies", "cli"):
        (core / folder).mkdir(parents=True)
        (core / folder / "__init__.py").write_text("")
    (tmp_path / "__init__.py").write_text("from . import viewer\n")
    (tmp_path / "viewer.py").write_text("import bpy\nfrom .vdnif_addon.blender import a\n")
    (core / "__init__.py").write_text("")
    (core / "x.py").write_text("def f():\n    from .y import g\n    import bpy\n")
    (core / "y.py").write_text("from . import x\nfrom .studies.s import run\n")
    (core / "blender" / "a.py").write_text("import bpy\nfrom ..cli import main\n")
    (core / "studies" / "s.py").write_text("from ..blender import a\nfrom .. import cli\n")
    (core / "batch.py").write_text("def m():\n    from vdnif_addon.cli import main\n")
    # A type-only import never runs: no edge (z would otherwise close a cycle with x).
    (core / "z.py").write_text("from typing import TYPE_CHECKING\nfrom . import x\n"
                               "if TYPE_CHECKING:\n    from .y import g\n")
    files, edges, external = import_graph(tmp_path)
    assert edges[f"{CORE}.z"] == {f"{CORE}.x"}
    assert edges["viewer"] == {f"{CORE}.blender.a"} and edges[""] == {"viewer"}
    assert edges[f"{CORE}.y"] == {f"{CORE}.x", f"{CORE}.studies.s"}
    assert cycles(edges) == [[f"{CORE}.x", f"{CORE}.y"]]
    assert stage_problems({f"{CORE}.geometry.g": {f"{CORE}.kernels.k"},
                           f"{CORE}.kernels.k": {f"{CORE}.geometry.g", f"{CORE}.errors"},
                           f"{CORE}.errors": set()}) == [
        f"{CORE}.geometry.g imports {CORE}.kernels.k, a later layer"]
    assert layering_problems(edges, external) == [
        f"{CORE}.blender.a imports {CORE}.cli, which sits above it",
        f"{CORE}.studies.s imports {CORE}.cli: studies sit below the commands",
        f"{CORE}.x imports bpy outside the Blender layers",
        f"{CORE}.y imports {CORE}.studies.s, which sits above it",
    ]
