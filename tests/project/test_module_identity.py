"""One identity of the core per test file. Blender tests load the package as the installed
extension (conftest's ``extension`` fixture and those built on it: the core then lives under
``bl_ext.dev.vdnif.vdnif_addon``); pure-core tests import ``vdnif_addon`` directly. A file
that does both holds two copies of a module (two ``VDNIFError`` classes, two ``RECIPE``
dataclasses), so ``pytest.raises`` or ``==`` across them can miss. A Blender test file
takes every core module through ``core(...)``, and an oracle of tests/oracles/ through
conftest's ``extension_oracle``; helpers it shares with pure tests (batch_runner,
oracle_network) import nothing of the core themselves.

Read from the sources with ast: every import (those inside functions too; a helper or test
file imported counts with what it imports) and every fixture a test or fixture asks for.
"""

import ast
import pathlib

REPO = pathlib.Path(__file__).resolve().parents[2]
TESTS = REPO / "tests"
CORE = "vdnif_addon"
ROOT_FIXTURE = "extension"     # conftest's fixture that enables the extension
# The tests/ helper that imports a script of tools/, which imports the core directly.
TOOL_LOADER = "load_tool"


def _is_fixture(function):
    return any("fixture" in ast.unparse(decorator) for decorator in function.decorator_list)


def _fixtures(tree):
    """{name: names of its parameters} of the functions decorated as pytest fixtures."""
    return {node.name: {arg.arg for arg in node.args.args} for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef) and _is_fixture(node)}


def extension_fixtures(trees):
    """Names of the fixtures of ``trees`` (conftest's and a test file's) that need the
    extension, directly or through another fixture."""
    fixtures = {}
    for tree in trees:
        fixtures.update(_fixtures(tree))
    needing = {ROOT_FIXTURE}
    grown = True
    while grown:
        more = {name for name, params in fixtures.items() if params & needing} - needing
        needing |= more
        grown = bool(more)
    return needing


def _imported(node):
    """Dotted names an import statement (level 0) loads: ``from a import b`` gives a and
    a.b (b may be a module of package a)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom) and not node.level and node.module:
        return [node.module, *(f"{node.module}.{alias.name}" for alias in node.names)]
    return []


def _is_main_block(node):
    """``if __name__ == "__main__":``, code that runs as a script, never under pytest."""
    return isinstance(node, ast.If) and ast.unparse(node.test) in (
        "__name__ == '__main__'", "'__main__' == __name__")


def _walk(tree):
    """Every node of ``tree`` outside its script blocks."""
    skipped = {id(inner) for node in ast.walk(tree) if _is_main_block(node)
               for inner in ast.walk(node)}
    return [node for node in ast.walk(tree) if id(node) not in skipped]


def direct_helpers(folder):
    """Dotted names of the modules and packages of ``folder`` (tests/; conftest aside) that
    import the core directly, themselves or through another of them: the oracles, and a test
    file another one imports a helper from."""
    uses = {}
    for path in folder.rglob("*.py"):
        parts = path.relative_to(folder).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if parts == ("conftest",):
            continue
        # A folder that is no package (a stage's tests, support/) is on the import path
        # itself: its modules are imported by their own name.
        if len(parts) > 1 and not (folder / parts[0] / "__init__.py").exists():
            parts = parts[1:]
        tree = ast.parse(path.read_text(), str(path))
        uses[".".join(parts)] = {name for node in _walk(tree) for name in _imported(node)}
    direct = set()
    grown = True
    while grown:
        more = {name for name, names in uses.items()
                if any(used.split(".")[0] == CORE or used in direct for used in names)}
        grown = bool(more - direct)
        direct |= more
    return direct


def identities(path, conftest_tree, helpers):
    """{"direct": [evidence], "extension": [evidence]} of test file ``path``, each entry
    "LINE: what" (an empty list where the file does not use that identity)."""
    tree = ast.parse(path.read_text(), str(path))
    needing = extension_fixtures([conftest_tree, tree])
    found = {"direct": [], "extension": []}
    for node in _walk(tree):
        names = _imported(node)
        if any(name.split(".")[0] == CORE for name in names):
            found["direct"].append(f"{node.lineno}: imports {CORE}")
        elif any(name in helpers for name in names):
            helper = next(name for name in names if name in helpers)
            found["direct"].append(f"{node.lineno}: imports {helper}, which imports {CORE}")
        if isinstance(node, ast.Call):
            callee = ast.unparse(node.func)
            first = node.args[0] if node.args else None
            if callee.endswith("import_module") and isinstance(first, ast.Constant) and str(
                    first.value).split(".")[0] == CORE:
                found["direct"].append(f"{node.lineno}: imports {first.value}")
            if callee == TOOL_LOADER:
                found["direct"].append(f"{node.lineno}: loads a tool")
            if callee.endswith("usefixtures") and any(
                    isinstance(arg, ast.Constant) and arg.value in needing for arg in node.args):
                found["extension"].append(f"{node.lineno}: uses the extension's fixtures")
        # Tests and fixtures ask for fixtures; a helper handed ``core`` is called by one.
        if isinstance(node, ast.FunctionDef) and (node.name.startswith("test")
                                                  or _is_fixture(node)):
            asked = sorted({arg.arg for arg in node.args.args} & needing)
            if asked:
                found["extension"].append(f"{node.lineno}: {node.name} asks for "
                                          f"{', '.join(asked)}")
    return found


def mixed_files(folder):
    """{file name: its evidence of both identities} for the test files of ``folder`` that
    use both."""
    conftest = ast.parse((folder / "conftest.py").read_text())
    helpers = direct_helpers(folder)
    mixed = {}
    for path in sorted(folder.rglob("test_*.py")):
        found = identities(path, conftest, helpers)
        if found["direct"] and found["extension"]:
            mixed[path.name] = found["direct"][:3] + found["extension"][:3]
    return mixed


def test_no_test_file_loads_the_core_under_both_identities():
    assert mixed_files(TESTS) == {}


def test_the_check_reads_the_suites_identities():
    """A guard on the reading: known files come out with the identity they use."""
    conftest = ast.parse((TESTS / "conftest.py").read_text())
    helpers = direct_helpers(TESTS)
    assert {"oracles.walk", "test_render"} <= helpers
    assert not {"oracles", "scene_builders", "batch_runner", "oracle_network"} & helpers
    assert {"extension", "core", "empty_scene"} <= extension_fixtures([conftest])
    scenes = identities(TESTS / "posed" / "test_stability_scenes.py", conftest, helpers)
    assert scenes["extension"] and not scenes["direct"]
    walk = identities(TESTS / "kernels" / "test_walk_kernel.py", conftest, helpers)
    assert walk["direct"] and not walk["extension"]


def test_the_check_finds_a_file_that_mixes_them(tmp_path):
    """Planted: a fixture built on ``core`` beside a direct import inside a test, a helper
    that imports the core, a test file imported for its helper, a tool loaded by path; and
    files that keep to one identity (a script block aside, the extension named in a string)."""
    (tmp_path / "conftest.py").write_text(
        "import pytest\n\n@pytest.fixture\ndef extension():\n    pass\n\n"
        "@pytest.fixture\ndef core(extension):\n    pass\n")
    (tmp_path / "helper").mkdir()
    (tmp_path / "helper" / "__init__.py").write_text("")
    (tmp_path / "helper" / "deep.py").write_text("from vdnif_addon.passes import Passes\n")
    (tmp_path / "test_pure.py").write_text("import vdnif_addon.errors\n\nclass Stub:\n    pass\n")
    (tmp_path / "test_mixed.py").write_text(
        "import pytest\n\n@pytest.fixture\ndef arm(core):\n    return core('scenes')\n\n"
        "def test_a(arm):\n    from vdnif_addon.errors import VDNIFError\n")
    (tmp_path / "test_helper.py").write_text(
        "import pytest\nfrom helper import deep\n\n"
        "@pytest.mark.usefixtures('extension')\ndef test_b():\n    pass\n")
    (tmp_path / "test_borrow.py").write_text(
        "def test_c(core):\n    from test_pure import Stub\n")
    (tmp_path / "test_tool.py").write_text(
        "from tool_errors import load_tool\n\ndef test_d(core):\n    load_tool('t.py')\n")
    (tmp_path / "test_one.py").write_text(
        "import importlib\n\ndef test_e(core):\n    core('errors')\n\n"
        "def test_f(extension):\n"
        "    importlib.import_module('bl_ext.dev.vdnif.vdnif_addon.errors')\n\n"
        "if __name__ == '__main__':\n    import vdnif_addon.errors\n")
    assert mixed_files(tmp_path) == {
        "test_borrow.py": ["2: imports test_pure, which imports vdnif_addon",
                           "1: test_c asks for core"],
        "test_helper.py": ["2: imports helper.deep, which imports vdnif_addon",
                           "4: uses the extension's fixtures"],
        "test_mixed.py": ["8: imports vdnif_addon", "4: arm asks for core",
                          "7: test_a asks for arm"],
        "test_tool.py": ["4: loads a tool", "3: test_d asks for core"],
    }
