"""Every results table describes today's default network or says which one it describes.

A results JSON written since the provenance record (``vdnif_addon.model.provenance``) carries the
hash of the default network of its run; the files committed before it are classified in
``docs/results/provenance.json`` (by their model bytes where they hold them). Each section of
docs/results.md and docs/performance.md that names a file whose network is not today's must
say so in its network's phrase ("network before the normal field", ...), and the table at the
top of docs/results.md names every file's network. Reads only the repository's JSON and
Markdown.
"""

import copy
import json
import pathlib
import re

from vdnif_addon.model.provenance import network_hash
from vdnif_addon.settings import OCCLUSION_CALIBRATION

REPO = pathlib.Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
INDEX = DOCS / "results" / "provenance.json"
RESULT_FOLDERS = ("results", "bench", "side-by-side")
MARKDOWN = ("results.md", "performance.md")
TABLE_HEADING = "Where each table comes from"
TODAYS_TRAINING = "today's training"
LEAST_SUM = "least-sum threshold"
"""How the table at the top of docs/results.md says that a row's models calibrated the
occlusion threshold on the least sum of holes and extras, as training did before
``settings.OCCLUSION_CALIBRATION``."""


def sections(text):
    """[(heading, its text up to the next heading of any level)] of a Markdown text."""
    parts, heading, lines = [], None, []
    for line in text.splitlines():
        if line.startswith("#"):
            if heading is not None:
                parts.append((heading, "\n".join(lines)))
            heading, lines = line.lstrip("#").strip(), []
        else:
            lines.append(line)
    if heading is not None:
        parts.append((heading, "\n".join(lines)))
    return parts


def at(data, path):
    for key in path:
        data = data[key]
    return data


def stamped_hashes(data):
    """The network hashes a results JSON records (a list's rows each their own); None where
    it records none (written before the provenance record)."""
    records = data if isinstance(data, list) else [data]
    hashes = {(row.get("provenance") or {}).get("network_hash") for row in records
              if isinstance(row, dict)}
    return None if hashes == {None} else hashes


def problems(index, files, docs, today):
    """What does not hold: ``files`` {name relative to docs/: its JSON}, ``docs`` {Markdown
    name: text}, ``today`` today's network hash."""
    found = []
    networks = {name: dict(entry, hash=None if entry["config"] is None
                           else network_hash(entry["config"]))
                for name, entry in index["networks"].items()}
    known = {entry["hash"]: name for name, entry in networks.items()}

    def stale(network):
        return networks[network]["hash"] not in (None, today)

    def said(doc, heading, body, network, what):
        phrase = networks[network]["phrase"]
        if phrase is None:
            found.append(f"{what} describes '{network}', not today's network ({today}): "
                         "give that network a phrase in provenance.json and say it there")
        elif phrase.lower() not in " ".join(body.lower().split()):
            found.append(f"{doc}, section '{heading}': {what} describes "
                         f"{networks[network]['label']}, and the section does not say "
                         f"'{phrase}'")

    for name, data in sorted(files.items()):
        entry = index["files"].get(name)
        hashes = stamped_hashes(data)
        if hashes is not None:
            unknown = [h for h in hashes if h != today and h not in known]
            found += [f"{name} describes network {h}, neither today's ({today}) nor one "
                      "provenance.json names" for h in unknown]
            main = [known[h] for h in hashes if h in known and stale(known[h])]
        elif entry is None:
            found.append(f"{name} records no network and provenance.json does not classify it")
            continue
        else:
            network = entry["network"]
            main = [network] if stale(network) else []
            if "model_bytes" in entry:
                low, high = networks[network]["model_bytes"][
                    "textured" if entry["textured"] else "untextured"]
                size = at(data, entry["model_bytes"])
                if not low <= size <= high:
                    found.append(f"{name}: a model of {size:,} bytes is not one of "
                                 f"'{network}' ({low:,}-{high:,})")
        overrides = (entry or {}).get("sections", {})
        for doc, text in docs.items():
            for heading, body in sections(text):
                # the table at the top names every file's network in a column of its own
                if heading == TABLE_HEADING or not re.search(
                        rf"(?<![\w-]){re.escape(name)}", body):
                    continue
                named = [overrides[key] for key in overrides if heading.startswith(key)]
                for network in named or main:
                    if stale(network):
                        said(doc, heading, body, network, name)
    for name in index["files"]:
        if name not in files:
            found.append(f"provenance.json classifies {name}, which is not there")
    for doc, tables in index.get("tables_without_json", {}).items():
        for key, network in tables.items():
            matching = [(h, b) for h, b in sections(docs[doc]) if h.startswith(key)]
            if not matching:
                found.append(f"{doc} has no section '{key}'")
            for heading, body in matching:
                if stale(network):
                    said(doc, heading, body, network, "its table")
    return found


def repository():
    index = json.loads(INDEX.read_text())
    files = {str(path.relative_to(DOCS)): json.loads(path.read_text())
             for folder in RESULT_FOLDERS for path in sorted((DOCS / folder).glob("*.json"))
             if path != INDEX}
    docs = {name: (DOCS / name).read_text() for name in MARKDOWN}
    return index, files, docs


def test_every_table_describes_todays_network_or_says_which():
    index, files, docs = repository()
    assert problems(index, files, docs, network_hash()) == []
    # the classification is not empty: today's network is one of the index's
    assert network_hash() in {network_hash(n["config"]) for n in index["networks"].values()
                              if n["config"] is not None}


def test_a_table_of_another_network_fails_unless_it_says_so():
    index, files, docs = repository()
    today = network_hash()
    # a new run's JSON stamped with a network nobody named
    other = copy.deepcopy(files)
    other["results/spot-shadow-seeds.json"]["provenance"] = {"network_hash": "0123456789ab"}
    assert any("0123456789ab" in p for p in problems(index, other, docs, today))
    # the same file stamped with today's network passes
    other["results/spot-shadow-seeds.json"]["provenance"] = {"network_hash": today}
    assert problems(index, other, docs, today) == []
    # a table of the network before the normal field, classified by its model's bytes, in a
    # section that says so
    stale = "results/old-study.json"
    old_files = dict(files, **{stale: {"runs": {"arm/proposed": {"model_bytes": 1_640_297}}}})
    old_index = copy.deepcopy(index)
    old_index["files"][stale] = {"network": "normal head", "evidence": "a test's",
                                 "model_bytes": ["runs", "arm/proposed", "model_bytes"],
                                 "textured": False}
    said = dict(docs, **{"results.md": docs["results.md"] + "\n## An old table\n\nNetwork "
                         "before the normal field: `results/old-study.json`.\n"})
    assert problems(old_index, old_files, said, today) == []
    # the sentence next to the stale table removed
    cut = dict(said, **{"results.md": re.sub("network before the normal field", "network",
                                             said["results.md"], flags=re.I)})
    assert any("old-study.json" in p for p in problems(old_index, old_files, cut, today))
    # the stale file relabelled as today's: its model bytes give it away
    relabelled = copy.deepcopy(old_index)
    relabelled["files"][stale]["network"] = "own grid"
    assert any("1,640,297 bytes" in p for p in problems(relabelled, old_files, said, today))
    # today's default network changes: every table of the old one is stale and unsaid
    assert any("give that network a phrase" in p
               for p in problems(index, files, docs, network_hash({"width": 128})))
    # a file nobody classified
    unlisted = dict(files, **{"results/new-study.json": {"rows": []}})
    assert any("new-study.json" in p for p in problems(index, unlisted, docs, today))


def index_rows(results_md):
    """{JSON name: the cells of its row} of the table at the top of docs/results.md."""
    body = dict(sections(results_md))[TABLE_HEADING]
    return {cells[0].strip("` "): cells for cells in
            ([c.strip() for c in line.strip().strip("|").split("|")]
             for line in body.splitlines() if line.startswith("| `"))}


def calibration_problems(files, results_md, today):
    """Rows of the index table whose recipe says today's training but whose JSON records
    another calibration of the occlusion threshold than ``today``'s (or none, written
    before it was recorded) without saying LEAST_SUM, or that say it of a JSON of today's."""
    found = []
    for name, cells in index_rows(results_md).items():
        if name not in files:
            continue
        records = files[name] if isinstance(files[name], list) else [files[name]]
        recorded = {((row.get("provenance") or {}).get("recipe") or {}).get(
            "occlusion_calibration") for row in records if isinstance(row, dict)}
        recipe = cells[3].lower()
        if recorded == {today}:
            if LEAST_SUM in recipe:
                found.append(f"{name} records today's calibration, its row says "
                             f"'{LEAST_SUM}'")
        elif TODAYS_TRAINING in recipe and LEAST_SUM not in recipe:
            found.append(f"{name}: its row says {TODAYS_TRAINING}, but its models "
                         "calibrated the occlusion threshold otherwise "
                         f"({sorted(map(str, recorded))}): say '{LEAST_SUM}'")
    return found


def test_every_row_of_todays_training_records_todays_calibration():
    index, files, docs = repository()
    assert calibration_problems(files, docs["results.md"], OCCLUSION_CALIBRATION) == []


def test_a_row_of_another_calibration_fails_unless_it_says_so():
    index, files, docs = repository()
    rows = index_rows(docs["results.md"])
    labelled = [name for name, cells in rows.items() if LEAST_SUM in cells[3].lower()]
    assert labelled, "no row to check the rule on"
    name = labelled[0]
    # its label removed: the row claims today's training
    cut = docs["results.md"].replace(rows[name][3], rows[name][3].replace(
        "with the " + LEAST_SUM, "").replace(LEAST_SUM, ""), 1)
    assert any(name in p for p in calibration_problems(files, cut, OCCLUSION_CALIBRATION))
    # the same file stamped with today's calibration: now the label is wrong
    stamped = dict(files, **{name: {"provenance": {"recipe": {
        "occlusion_calibration": OCCLUSION_CALIBRATION}}}})
    assert any(name in p for p in calibration_problems(stamped, docs["results.md"],
                                                         OCCLUSION_CALIBRATION))
    # rerun and its label removed, it passes, until today's calibration changes again
    assert not any(name in p for p in calibration_problems(stamped, cut,
                                                             OCCLUSION_CALIBRATION))
    assert any(name in p for p in calibration_problems(stamped, cut, "another rule"))


def test_results_md_names_every_files_network():
    """The table at the top of docs/results.md: one row per results JSON, its network the
    one provenance.json gives it (or its own record's)."""
    index, files, docs = repository()
    body = dict(sections(docs["results.md"]))[TABLE_HEADING]
    rows = {cells[0].strip("` "): cells for cells in
            ([c.strip() for c in line.strip().strip("|").split("|")]
             for line in body.splitlines() if line.startswith("| `"))}
    for name in (n for n in files if n.startswith("results/")):
        assert name in rows, name
        network = index["files"][name]["network"]
        assert rows[name][4].startswith(index["networks"][network]["label"]), (name, rows[name])
