"""tools/seed_spread_check.py: a median now is better, within or worse against the earlier
run's smallest and largest seed, per metric and reference, and a commit without the file
ends in one error line."""

import itertools
import json
import pathlib

import pytest
from tool_errors import load_tool, one_error_line

from vdnif_addon.errors import VDNIFError

TOOL = pathlib.Path(__file__).resolve().parents[2] / "tools" / "seed_spread_check.py"


def report(median, seeds):
    """An experiment JSON's runs: one run whose metrics all take ``median`` (the table's figure)
    and, per seed, the values of ``seeds``."""
    def metrics(value):
        return {"distance_mae": value, "normal_error_deg": 10 * value,
                "false_negative_rate": value / 100, "false_positive_rate": value / 100}

    def both(value):
        return {"vs_true": metrics(value), "vs_embedded": metrics(value)}

    return {"arm/proposed": {"common": both(median),
                             "seeds": [{"common": both(v)} for v in seeds]},
            "arm/original (rest pose)": both(median)}


def test_each_median_is_placed_against_the_earlier_seeds():
    tool = load_tool(TOOL)
    before = report(2.0, [1.0, 2.0, 3.0])
    for median, verdict in ((0.5, "better"), (1.0, "within"), (3.0, "within"),
                            (3.5, "worse")):
        rows = tool.compare(before, report(median, [median] * 3))
        # four metrics against two references; the run without seeds is left out
        assert len(rows) == 8
        assert {row["verdict"] for row in rows} == {verdict}
        assert {(row["before_min"], row["before_max"]) for row in rows
                if row["metric"] == "distance_mae"} == {(1.0, 3.0)}
    lines = tool.table(tool.compare(before, report(3.5, [3.5]))).splitlines()
    assert "**worse**" in lines[2] and "3.5 %" in "".join(lines)


def test_a_file_missing_now_ends_in_one_error_line():
    line = one_error_line(TOOL, ["--before", "HEAD", "--then", "docs/results.md", "--now",
                                 "docs/results/no-such.json"])
    assert "no-such.json" in line


def test_a_file_missing_at_the_earlier_commit_is_named():
    with pytest.raises(VDNIFError, match="no-such.json' at HEAD"):
        load_tool(TOOL).committed("docs/results/no-such.json", "HEAD")


@pytest.mark.parametrize("before, now", [(3, 3), (3, 1), (5, 3), (2, 5)])
def test_the_chance_of_a_figure_beyond_the_earlier_seeds_counts_every_ordering(before, now):
    """Against brute force: every ordering of the pooled draws is equally likely when nothing
    changed; the median now lies above the earlier largest, and every draw now above every
    earlier one, in the counted share of them."""
    tool = load_tool(TOOL)
    beyond = apart = 0
    orderings = list(itertools.permutations(range(before + now)))
    for ranks in orderings:
        earlier, later = ranks[:before], sorted(ranks[before:])
        beyond += later[now // 2] > max(earlier)
        apart += later[0] > max(earlier)
    assert tool.beyond_by_chance(before, now) == pytest.approx(beyond / len(orderings))
    assert tool.separated_by_chance(before, now) == pytest.approx(apart / len(orderings))
    assert tool.beyond_by_chance(3, 3) == pytest.approx(1 / 5)


def test_every_seed_beyond_every_earlier_seed_is_told_from_an_overlap():
    tool = load_tool(TOOL)
    before = report(2.0, [1.0, 2.0, 3.0])
    for seeds, word in (([3.5, 4.0, 5.0], "worse"), ([2.5, 3.5, 4.0], "overlapping"),
                        ([0.1, 0.5, 0.9], "better")):
        rows = tool.compare(before, report(seeds[1], seeds))
        assert {row["separated"] for row in rows} == {word}
        assert {(row["now_min"], row["now_max"]) for row in rows
                if row["metric"] == "distance_mae"} == {(seeds[0], seeds[2])}
    with pytest.raises(VDNIFError, match="odd count"):
        tool.beyond_by_chance(3, 2)


SPREAD = "docs/results/deformation-arm-lattice.json"


def test_a_rerun_replaces_its_own_rows(tmp_path):
    tool = load_tool(TOOL)
    out = tmp_path / "spread.json"
    for _ in range(2):
        tool.main(["--before", "HEAD", "--then", SPREAD, "--now", SPREAD, "--json", str(out)])
        record = json.loads(out.read_text())
        assert next(iter(record)) == "format" and record["format"] == tool.FORMAT
        assert record["rows"] and "provenance" in record
