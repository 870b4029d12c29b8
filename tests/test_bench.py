"""The speed/accuracy sweep: its Pareto front and presets against hand-checked answers, and
``bench --quick`` end to end."""

import csv
import json

import pytest

from test_batch import run_batch
from vdnif_addon.errors import VDNIFError
from vdnif_addon.presets import (PRESETS_FILE, SETTINGS, derive_presets, load_presets,
                                  pareto_front)


def test_pareto_front_keeps_only_undominated_points():
    error = [0.10, 0.05, 0.20, 0.05, 0.02, 0.30]
    cost = [1.0, 2.0, 0.5, 3.0, 5.0, 0.4]
    # (0.05, 3.0) is beaten by (0.05, 2.0); every other point wins on error or on cost
    assert pareto_front(error, cost) == [5, 2, 0, 1, 4]
    assert pareto_front([1.0, 1.0], [2.0, 2.0]) == [0]


def point(error, speed, resolution):
    return dict(dict.fromkeys(SETTINGS, 1), resolution=resolution, error=error,
                render_rays_per_s=speed)


def test_presets_are_the_fastest_the_knee_and_the_most_accurate_of_the_front():
    points = [point(0.08, 1000.0, 16), point(0.04, 900.0, 24), point(0.01, 100.0, 64),
              point(0.09, 500.0, 8)]                     # the last one is dominated
    presets = derive_presets(points)
    assert [presets[name]["resolution"] for name in ("fast", "balanced", "accurate")] == [
        16, 24, 64]
    assert presets["balanced"]["measured"] == {"error": 0.04, "render_rays_per_s": 900.0}
    with pytest.raises(VDNIFError, match="no sweep point has both"):
        derive_presets([point(None, 10.0, 8)])


def test_shipped_presets_come_from_a_full_sweep():
    shipped = json.loads(PRESETS_FILE.read_text())
    assert shipped["source"] == "bench"                   # not a --quick run
    presets = load_presets()
    assert presets["fast"]["measured"]["render_rays_per_s"] >= \
        presets["balanced"]["measured"]["render_rays_per_s"] >= \
        presets["accurate"]["measured"]["render_rays_per_s"]
    errors = [presets[name]["measured"]["vs_true_distance_mae"]
              for name in ("fast", "balanced", "accurate")]
    assert errors == sorted(errors, reverse=True)


def test_bad_presets_files_are_refused(tmp_path):
    broken = tmp_path / "presets.json"
    broken.write_text(json.dumps({"presets": {"fast": {}}}))
    with pytest.raises(VDNIFError, match="does not hold fast, balanced, accurate"):
        load_presets(broken)
    with pytest.raises(VDNIFError, match="cannot be read"):
        load_presets(tmp_path / "missing.json")


def test_bench_quick_writes_every_output(tmp_path):
    out, presets, performance = tmp_path / "bench", tmp_path / "p.json", tmp_path / "perf.md"
    code, printed, err = run_batch("bench", "--quick", "--out", out, "--presets", presets,
                                   "--performance", performance, timeout=600)
    assert code == 0, err
    rows = list(csv.DictReader(open(out / "bench.csv")))
    assert len(rows) == 6 == len(json.loads((out / "bench.json").read_text()))
    assert {row["resolution"] for row in rows} == {"12", "16"}
    assert sum(row["vs_true_distance_mae"] != "" for row in rows) >= 2    # hits to compare
    assert (out / "pareto.png").stat().st_size > 10_000
    assert set(load_presets(presets)) == {"fast", "balanced", "accurate"}
    text = performance.read_text()
    assert text.startswith("# Performance") and "## Speed/accuracy sweep" in text
    assert "![Pareto fronts](bench/pareto.png)" in text
