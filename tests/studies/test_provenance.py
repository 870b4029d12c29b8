"""A results JSON records what produced it: the commit, today's default network with its
hash, the recipe's defaults and, where it holds times, the machine; and every module that
writes a results JSON stamps it."""

import ast
import dataclasses
import json
import pathlib
import re

from vdnif_addon import settings
from vdnif_addon.kernels import runtime
from vdnif_addon.model import provenance

REPO = pathlib.Path(__file__).resolve().parents[2]
# Where results JSON is written: the studies, the batch commands' --json, the tools.
WRITERS = ("vdnif_addon/studies", "vdnif_addon/cli", "tools")
JSON_WRITE = re.compile(r"write_json_atomic\(|write_text\(json\.dumps")
# Modules whose JSON writes are no results of their own: each with why.
NOT_RESULTS = {
    "vdnif_addon/studies/bench_report.py": "writes the sweep's rows, each with the provenance "
                                           "its point's training record took (bench.py)",
    "vdnif_addon/cli/options.py": "write_json itself, which stamps what it writes",
}


def test_a_stamp_names_the_commit_todays_network_and_the_recipe(monkeypatch):
    monkeypatch.setattr(provenance, "commit", lambda repo=None: "0" * 40)
    data = {"rows": [1, 2]}
    stamped = provenance.stamp(data)
    assert data == {"rows": [1, 2]}                     # the caller's data is not changed
    record = stamped["provenance"]
    assert stamped["rows"] == [1, 2] and "machine" not in record
    assert record["commit"] == "0" * 40
    network = {k: v for k, v in settings.NetworkConfig().to_dict().items() if k != "heads"}
    assert record["network"] == network
    assert re.fullmatch(r"[0-9a-f]{12}", record["network_hash"])
    assert record["network_hash"] == provenance.network_hash()
    assert record["recipe"]["data"] == dataclasses.asdict(settings.RECIPE)
    assert record["recipe"]["training"]["lr_mlp"] == settings.TrainConfig().lr_mlp
    assert record["recipe"]["resolution_rules"]["textured"] == settings.RECIPE.textured_resolution


def test_a_report_of_a_model_trained_otherwise_is_stamped_with_its_network(monkeypatch,
                                                                          tmp_path):
    """A report that holds its model's network (``evaluate --json``, the demo's report:
    ``config["network"]``) names that network, so that a table of a model with other
    settings is not taken for one of today's default; a report without one names today's
    default. ``stamp`` decides it, so every writer stamps alike."""
    from vdnif_addon.cli.options import write_json

    monkeypatch.setattr(provenance, "commit", lambda repo=None: "0" * 40)
    other = dict(settings.NetworkConfig(levels=3).to_dict())
    write_json(tmp_path / "model.json", {"config": {"network": other}, "vs_true": {}})
    write_json(tmp_path / "plain.json", {"rows": []})
    model = json.loads((tmp_path / "model.json").read_text())["provenance"]
    plain = json.loads((tmp_path / "plain.json").read_text())["provenance"]
    assert model["network"]["levels"] == 3 and "heads" not in model["network"]
    assert model["network_hash"] == provenance.network_hash(
        {k: v for k, v in other.items() if k != "heads"}) != provenance.network_hash()
    assert plain["network_hash"] == provenance.network_hash()
    today = dict(settings.NetworkConfig().to_dict())        # a default model: today's hash
    write_json(tmp_path / "default.json", {"config": {"network": today}})
    assert json.loads((tmp_path / "default.json").read_text())["provenance"][
        "network_hash"] == provenance.network_hash()
    assert provenance.stamp({"config": {"network": other}})["provenance"]["network_hash"] == \
        model["network_hash"]


def test_the_hash_changes_with_any_field_of_the_network():
    today = provenance.default_network()
    for key, value in today.items():
        changed = dict(today, **{key: (value + 1 if isinstance(value, (int, float))
                                       and not isinstance(value, bool) else f"{value}-other")})
        assert provenance.network_hash(changed) != provenance.network_hash(today), key
    # the order of the fields does not matter
    assert provenance.network_hash(dict(reversed(today.items()))) == provenance.network_hash()


def test_times_come_with_the_machine_and_its_load(monkeypatch):
    monkeypatch.setattr(provenance, "commit", lambda repo=None: "unknown")
    monkeypatch.setattr(runtime, "_cpuinfo", lambda: ["model name\t: Test CPU 9000",
                                                      "flags\t\t: avx2 fma"])
    monkeypatch.setattr(provenance.os, "getloadavg", lambda: (1.5, 2.0, 2.5))
    machine = provenance.stamp({}, with_machine=True)["provenance"]["machine"]
    assert machine["cpu"] == "Test CPU 9000"
    assert machine["load_average"] == [1.5, 2.0, 2.5]
    assert machine["cores"] >= 1 and "omp_num_threads" in machine and "torch_threads" in machine


def test_outside_a_checkout_the_commit_is_unknown(tmp_path):
    assert provenance.commit(tmp_path) == "unknown"


def test_every_module_that_writes_results_json_stamps_it():
    unstamped = []
    for folder in WRITERS:
        for path in sorted((REPO / folder).rglob("*.py")):
            relative = path.relative_to(REPO).as_posix()
            source = path.read_text()
            if not JSON_WRITE.search(source) or relative in NOT_RESULTS:
                continue
            names = {node.id if isinstance(node, ast.Name) else node.attr
                     for node in ast.walk(ast.parse(source))
                     if isinstance(node, (ast.Name, ast.Attribute))}
            if not names & {"stamp", "provenance", "write_json"}:
                unstamped.append(relative)
    assert unstamped == []
