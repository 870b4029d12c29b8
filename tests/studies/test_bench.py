"""The speed/accuracy sweep: its Pareto front and presets against hand-checked answers, and
``bench --quick`` end to end."""

import csv
import json

import pytest
from batch_runner import run_batch
from conftest import REPO

from vdnif_addon.errors import VDNIFError
from vdnif_addon.inference.metrics import speed_withheld
from vdnif_addon.model.model_file import load_model
from vdnif_addon.pose_sets import DEVELOPMENT_POSES
from vdnif_addon.presets import (
    PRESET_ERROR,
    PRESET_NAMES,
    PRESETS_FILE,
    SETTINGS,
    SPEED_ROUNDS,
    load_presets,
    read_presets,
)
from vdnif_addon.safe_io import exclusive_lock
from vdnif_addon.studies.pareto import (
    derive_presets,
    measurably_faster,
    pareto_front,
    pick_presets,
    round_ratios,
)
from vdnif_addon.text import percent


def test_pareto_front_keeps_only_undominated_points():
    error = [0.10, 0.05, 0.20, 0.05, 0.02, 0.30]
    cost = [1.0, 2.0, 0.5, 3.0, 5.0, 0.4]
    # (0.05, 3.0) is beaten by (0.05, 2.0); every other point wins on error or on cost
    assert pareto_front(error, cost) == [5, 2, 0, 1, 4]
    assert pareto_front([1.0, 1.0], [2.0, 2.0]) == [0]


def point(error, speed, resolution):
    """A sweep point of a model that predicts hits (see test_metrics for one that does not)."""
    return dict(dict.fromkeys(SETTINGS, 1), resolution=resolution, error=error,
                render_rays_per_s=speed, vs_true_hit_iou=0.95)


def test_presets_are_the_fastest_the_knee_and_the_most_accurate_of_the_front():
    points = [point(0.08, 1000.0, 16), point(0.04, 900.0, 24), point(0.01, 100.0, 64),
              point(0.09, 500.0, 8)]                     # the last one is dominated
    presets = pick_presets(points)
    assert [presets[name]["resolution"] for name in ("fast", "balanced", "accurate")] == [
        16, 24, 64]
    assert presets["balanced"]["measured"] == {"error": 0.04, "render_rays_per_s": 900.0}
    with pytest.raises(VDNIFError, match="no sweep point has both"):
        pick_presets([point(None, 10.0, 8)])


def on_unit_front(unit_error, unit_cost, resolution):
    """A point whose log error and log cost, normalized over a front spanning 10x in each,
    are ``unit_error`` and ``unit_cost``."""
    return point(1e-3 * 10 ** unit_error, 1e6 / 10 ** unit_cost, resolution)


def test_balanced_is_the_knee_of_the_fronts_interior_points():
    # three front points: the middle one is balanced although, over the whole front, both
    # ends lie nearer the ideal corner (distance 1) than it does (hypot(0.98, 0.99))
    three = [on_unit_front(1, 0, 8), on_unit_front(0.98, 0.99, 16), on_unit_front(0, 1, 32),
             on_unit_front(1, 1, 64)]                     # the last one is dominated
    presets = pick_presets(three)
    assert [presets[name]["resolution"] for name in ("fast", "balanced", "accurate")] == [
        8, 16, 32]
    # five front points at hand-placed unit coordinates: distances to the corner 1 (end),
    # hypot(0.5, 0.1) = 0.51, hypot(0.2, 0.3) = 0.36, hypot(0.05, 0.8) = 0.80, 1 (end)
    five = [on_unit_front(e, c, r) for e, c, r in (
        (1, 0, 8), (0.5, 0.1, 12), (0.2, 0.3, 16), (0.05, 0.8, 24), (0, 1, 32),
        (0.3, 0.35, 48))]                                 # the last one is dominated
    presets = pick_presets(five)
    assert [presets[name]["resolution"] for name in ("fast", "balanced", "accurate")] == [
        8, 16, 32]


def test_a_two_point_front_takes_balanced_from_the_point_nearest_it():
    """Fast (0.02, 1000 rays/s) and accurate (0.01, 500 rays/s) are the front. A point
    that fast beats must gain min(ln(0.025 / 0.02), ln(1000 / 900)) = ln(1.111) = 0.105 in
    both to join it; one that accurate beats min(ln(0.011 / 0.01), ln(500 / 450)) =
    ln(1.1) = 0.095: the second is balanced."""
    fast, accurate = point(0.02, 1000.0, 16), point(0.01, 500.0, 64)
    by_fast, by_accurate = point(0.025, 900.0, 24), point(0.011, 450.0, 32)
    presets = pick_presets([fast, by_fast, by_accurate, accurate])
    assert [presets[name]["resolution"] for name in ("fast", "balanced", "accurate")] == [
        16, 32, 64]
    assert presets["balanced"]["measured"] == {"error": 0.011, "render_rays_per_s": 450.0}
    # beaten by fast 10 % less on each: the nearer one now
    nearer = point(0.02 * 1.09, 1000.0 / 1.09, 12)
    presets = pick_presets([fast, by_fast, by_accurate, accurate, nearer])
    assert presets["balanced"]["resolution"] == 12
    # no third point, or one point the fastest and the most accurate: refused
    with pytest.raises(VDNIFError, match="no third for balanced; widen the sweep"):
        pick_presets([fast, accurate])
    with pytest.raises(VDNIFError, match="both the fastest and the most accurate.*widen the "
                                         "sweep"):
        pick_presets([fast, point(0.03, 900.0, 8), point(0.04, 100.0, 12)])


def timed(rounds):
    """A point measured in timing ``rounds`` (rays/s), its speed their median."""
    return {SPEED_ROUNDS: rounds, "render_rays_per_s": sorted(rounds)[len(rounds) // 2]}


def test_a_speed_is_measurably_faster_only_when_it_is_faster_in_every_round():
    slow = timed([100.0, 110.0, 105.0])
    # faster in every round though the ranges of rounds overlap (109 < 110): the rounds are
    # compared one by one, as they were timed
    fast = timed([109.0, 150.0, 160.0])
    assert measurably_faster(fast, slow) and not measurably_faster(slow, fast)
    assert round_ratios(fast, slow) == pytest.approx([1.09, 150 / 110, 160 / 105])
    # faster on the median and the mean, slower in one round: not shown
    once_slower = timed([99.0, 150.0, 160.0])
    assert not measurably_faster(once_slower, slow) and not measurably_faster(slow, once_slower)
    # a tie in one round is not faster
    assert not measurably_faster(timed([100.0, 150.0, 160.0]), slow)
    # rounds of another count are not of the same sweep
    assert round_ratios(timed([200.0, 210.0]), slow) is None
    assert not measurably_faster(timed([200.0, 210.0]), slow)
    # without rounds (an older bench.json or presets file) no speed can be shown to differ,
    # however far apart the medians
    assert not measurably_faster({"render_rays_per_s": 1e6}, slow)
    assert not measurably_faster(fast, {"render_rays_per_s": 1.0})
    assert not measurably_faster(dict(fast, **{SPEED_ROUNDS: None}), slow)
    assert not measurably_faster(dict(fast, **{SPEED_ROUNDS: []}), slow)


def three_presets(fast_rounds, balanced_rounds, accurate_rounds):
    """A sweep whose front is three points, the fastest, the knee and the most accurate, with
    these timing rounds, and a dominated fourth (timed too)."""
    points = [dict(point(error, None, resolution), **timed(rounds))
              for error, resolution, rounds in ((0.08, 16, fast_rounds),
                                                (0.04, 24, balanced_rounds),
                                                (0.01, 64, accurate_rounds))]
    return points + [dict(point(0.09, None, 8), **timed([50.0, 60.0, 70.0]))]


def test_a_preset_not_measurably_faster_than_the_next_more_accurate_one_is_dropped():
    # each faster in every round: all three kept, each measured with its rounds
    presets, dropped = derive_presets(three_presets([900.0, 1000.0, 950.0], [600.0, 700.0, 650.0],
                                                    [300.0, 400.0, 350.0]))
    assert list(presets) == list(PRESET_NAMES) and dropped == {}
    assert presets["balanced"]["measured"] == {"error": 0.04, "render_rays_per_s": 650.0,
                                               SPEED_ROUNDS: [600.0, 700.0, 650.0]}
    # balanced slower than accurate in its second round: it buys nothing measurable and is
    # dropped; fast is then weighed against accurate, and is faster in every round
    presets, dropped = derive_presets(three_presets([900.0, 1000.0, 950.0], [420.0, 420.0, 440.0],
                                                    [400.0, 430.0, 410.0]))
    assert [presets[name]["resolution"] for name in presets] == [16, 64]
    assert dropped == {"balanced": "measured no faster than Accurate: faster in 2 of 3 timing "
                                   "rounds, 0.98-1.07x round by round"}
    # fast ties balanced in one round: fast is dropped, balanced kept
    presets, dropped = derive_presets(three_presets([700.0, 800.0, 750.0], [700.0, 700.0, 650.0],
                                                    [300.0, 400.0, 350.0]))
    assert list(presets) == ["balanced", "accurate"]
    assert dropped == {"fast": "measured no faster than Balanced: faster in 2 of 3 timing "
                               "rounds, 1.00-1.15x round by round"}
    # balanced dropped, and fast, faster than balanced in every round, slower than accurate
    # in one: fast is dropped too, against accurate
    presets, dropped = derive_presets(three_presets([500.0, 560.0, 530.0], [420.0, 480.0, 450.0],
                                                    [400.0, 570.0, 410.0]))
    assert list(presets) == ["accurate"] and list(dropped) == ["fast", "balanced"]
    assert dropped["fast"] == ("measured no faster than Accurate: faster in 2 of 3 timing "
                               "rounds, 0.98-1.29x round by round")
    # a sweep without rounds (an older bench.json): no preset is shown faster than another,
    # and accurate is kept alone, each of the others saying so with the medians
    untimed = [point(0.08, 1000.0, 16), point(0.04, 900.0, 24), point(0.01, 100.0, 64)]
    presets, dropped = derive_presets(untimed)
    assert list(presets) == ["accurate"]
    assert dropped == {
        "fast": "not shown faster than Accurate: no timing rounds recorded (1,000 rays/s "
                "against 100, medians)",
        "balanced": "not shown faster than Accurate: no timing rounds recorded (900 rays/s "
                    "against 100, medians)"}


def test_shipped_presets_come_from_a_full_sweep():
    shipped = json.loads(PRESETS_FILE.read_text())
    assert shipped["source"] == "bench"                   # not a --quick run
    presets, dropped = read_presets()
    # distinct points, accurate among them; each offered one faster and less accurate than
    # the next more accurate one offered
    assert "accurate" in presets and set(presets) | set(dropped) == set(PRESET_NAMES)
    assert len({tuple(presets[name][key] for key in SETTINGS) for name in presets}) == len(
        presets)
    offered = [presets[name]["measured"] for name in PRESET_NAMES if name in presets]
    for faster, slower in zip(offered, offered[1:]):
        assert faster["render_rays_per_s"] > slower["render_rays_per_s"]
        assert faster[PRESET_ERROR] > slower[PRESET_ERROR]


def test_shipped_presets_are_the_front_of_the_points_that_predict_hits():
    """The shipped presets follow from the shipped sweep by the rule that only models that
    predict hits (hit IoU >= 0.9 against the true reference) have a speed."""
    shipped = json.loads(PRESETS_FILE.read_text())
    rows = json.loads((REPO / "docs" / "bench" / "bench.json").read_text())
    assert shipped["error"] == PRESET_ERROR
    picked = pick_presets(rows, PRESET_ERROR)
    assert {name: picked[name] for name in shipped["presets"]} == shipped["presets"]
    assert derive_presets(rows, PRESET_ERROR) == (shipped["presets"], shipped["dropped"])
    # the same sweep without its timing rounds cannot show one preset faster than another:
    # accurate alone is kept
    untimed = [{key: entry for key, entry in row.items() if key != SPEED_ROUNDS}
               for row in rows]
    presets, dropped = derive_presets(untimed, PRESET_ERROR)
    assert list(presets) == ["accurate"] and set(dropped) == {"fast", "balanced"}
    assert {k: presets["accurate"][k] for k in SETTINGS} == {
        k: picked["accurate"][k] for k in SETTINGS}
    assert all("no timing rounds recorded" in reason for reason in dropped.values())
    # the same sweep with its most accurate point no longer predicting hits: that point
    # drops out of the presets (every point of the converged sweep predicts hits)
    best = min((row for row in rows if speed_withheld(row["vs_true_hit_iou"]) is None),
               key=lambda row: row[PRESET_ERROR])
    best["vs_true_hit_iou"] = 0.5
    accurate = derive_presets(rows, PRESET_ERROR)[0]["accurate"]
    assert accurate["measured"][PRESET_ERROR] > shipped["presets"]["accurate"]["measured"][
        PRESET_ERROR]


def test_bad_presets_files_are_refused(tmp_path):
    broken = tmp_path / "presets.json"
    broken.write_text(json.dumps({"presets": {"fast": {}}}))
    with pytest.raises(VDNIFError, match="does not hold fast, balanced, accurate"):
        load_presets(broken)
    with pytest.raises(VDNIFError, match="cannot be read"):
        load_presets(tmp_path / "missing.json")
    # a file an older bench wrote, its presets measured by another error
    older = json.loads(PRESETS_FILE.read_text())
    older["error"] = "vs_true_distance_mae"
    for preset in older["presets"].values():
        preset["measured"] = {"vs_true_distance_mae": 0.01, "render_rays_per_s": 1e5}
    broken.write_text(json.dumps(older))
    with pytest.raises(VDNIFError, match="measured common_vs_true_distance_mae"):
        load_presets(broken)
    older["presets"] = json.loads(PRESETS_FILE.read_text())["presets"]
    broken.write_text(json.dumps(older))
    with pytest.raises(VDNIFError, match="by 'vs_true_distance_mae', not "
                                         "'common_vs_true_distance_mae': run bench again"):
        load_presets(broken)
    # a file whose balanced repeats fast's settings (what a two-point front once gave)
    older["error"] = PRESET_ERROR
    older["presets"]["balanced"] = dict(older["presets"]["fast"])
    older.get("dropped", {}).pop("balanced", None)
    broken.write_text(json.dumps(older))
    with pytest.raises(VDNIFError, match="gives fast and balanced the same settings: run "
                                         "bench again"):
        load_presets(broken)


def presets_file(path, presets, **extra):
    """Writes a presets file of ``presets`` (and ``extra`` keys, ``dropped``) to ``path``."""
    path.write_text(json.dumps({"format": "vdnif-presets", "source": "bench",
                                "error": PRESET_ERROR, "presets": presets, **extra}))
    return path


def test_a_presets_file_may_drop_presets_each_name_offered_or_dropped(tmp_path):
    measured = {PRESET_ERROR: 0.01, "render_rays_per_s": 1e5}
    three = {name: dict(dict.fromkeys(SETTINGS, 2), width=16 * (i + 1), measured=measured)
             for i, name in enumerate(PRESET_NAMES)}
    # a file written before presets could be dropped, without rounds: every preset offered
    path = presets_file(tmp_path / "older.json", three)
    assert read_presets(path) == (three, {}) and load_presets(path) == three
    # balanced dropped: fast and accurate offered, balanced's reason kept
    reason = "measured no faster than Accurate: 427-446 k rays/s against 420-440 k"
    two = {name: three[name] for name in ("fast", "accurate")}
    path = presets_file(tmp_path / "two.json", two, dropped={"balanced": reason})
    assert read_presets(path) == (two, {"balanced": reason}) and load_presets(path) == two
    assert read_presets(presets_file(tmp_path / "one.json", {"accurate": three["accurate"]},
                                     dropped={"fast": reason, "balanced": reason}))[1] == {
        "fast": reason, "balanced": reason}
    refused = {
        "both offers and drops balanced: run bench again": (three, {"balanced": reason}),
        "neither offers nor drops balanced: run bench again": (two, {}),
        "drops every preset: run bench again": ({}, dict.fromkeys(PRESET_NAMES, reason)),
        "neither offers nor drops fast: run bench again": ({}, {}),
        # a name it does not know, a reason that says nothing or is not text
        "does not hold fast, balanced, accurate, each a preset": (two, {"balanced": reason,
                                                                         "quick": reason}),
        "does not hold fast, balanced, accurate, each a": (two, {"balanced": " "}),
        "does not hold fast, balanced, accurate, each": (two, {"balanced": 3}),
        "does not hold fast, balanced, accurate,": (two, [reason]),
    }
    for message, (presets, dropped) in refused.items():
        path = presets_file(tmp_path / "refused.json", presets, dropped=dropped)
        with pytest.raises(VDNIFError, match=f"^presets file '.*refused.json' {message}") as error:
            read_presets(path)
        assert "\n" not in str(error.value)


@pytest.mark.slow
def test_bench_quick_writes_every_output(tmp_path):
    from vdnif_addon.studies import bench

    out, presets, performance = tmp_path / "bench", tmp_path / "p.json", tmp_path / "perf.md"
    work = tmp_path / "work"
    work.mkdir()
    # another bench run on the same work folder is training point 3 (this process holds its
    # lock): this run trains the other four, passes point 3 by and leaves the evaluation
    # to the run that finishes last
    other = exclusive_lock(work / "point-2.lock")
    assert other is not None
    with other:
        code, printed, err = run_batch("bench", "--quick", "--out", out, "--presets", presets,
                                       "--performance", performance, "--work", work,
                                       timeout=600)
    assert code == 0, err
    assert sorted(p.name for p in work.glob("point-*.vdnif")) == [
        f"point-{n}.vdnif" for n in (0, 1, 3, 4)]
    assert "point 3 of 5 is training in another bench run" in err
    assert "no outputs written by this run" in printed and not out.exists()
    # the lock is free again (as when the other run stops): the next run trains point 3
    # alone and evaluates every point
    code, printed, err = run_batch("bench", "--quick", "--out", out, "--presets", presets,
                                   "--performance", performance, "--work", work, timeout=600)
    assert code == 0, err
    assert err.count("bench: point 3 of 5: ") == 1 and err.count("bench: point ") == 6
    # its dataset's corners keep the arm's copied armature, chosen once for that dataset
    assert err.count(": corners follow: armature copy (embedding error") == 1
    rows = list(csv.DictReader(open(out / "bench.csv")))
    records = json.loads((out / "bench.json").read_text())
    assert len(rows) == 5 == len(records)
    # each point records the network, commit and machine its training ran on; the CSV is flat
    assert all({"network_hash", "commit", "machine"} <= set(r["provenance"]) for r in records)
    assert "provenance" not in rows[0]
    assert sorted(p.name for p in work.glob("point-*.vdnif")) == [
        f"point-{n}.vdnif" for n in range(5)]
    assert {load_model(p)[1].corners_follow for p in work.glob("point-*.vdnif")} == {
        "armature copy"}
    # run again on the same work folder: nothing trains, every point is evaluated again
    # and scores as before (the speeds are measured anew)
    code, _, again = run_batch("bench", "--quick", "--out", out, "--presets", presets,
                               "--work", work, timeout=600)
    assert code == 0, again
    assert "train: step" not in again and again.count("evaluated from") == 5
    for before, after in zip(records, json.loads((out / "bench.json").read_text())):
        for key in ("steps", "converged", "vs_true_hit_iou", "vs_true_distance_mae",
                    "vs_embedded_normal_error_deg", "vs_true_false_negative_rate"):
            assert after[key] == before[key], key
    assert {row["resolution"] for row in rows} == {"12", "16"}
    # every point trained to the convergence rule: its steps, and whether it converged
    cap = bench.SIZES["quick"]["convergence"]["max_steps"]
    for record in records:
        assert 0 < record["steps"] <= cap
        assert record["converged"] or record["steps"] == cap   # only the rule stops early
    assert sum(row["vs_true_distance_mae"] != "" for row in rows) >= 2    # hits to compare
    assert (out / "pareto.png").stat().st_size > 10_000
    text = performance.read_text()
    assert text.startswith("# Performance") and "## Speed/accuracy sweep" in text
    assert "![Pareto fronts](bench/pareto.png)" in text
    # a speed, a common-set error and a preset only from points that predict hits
    for record in records:
        withheld = speed_withheld(record["vs_true_hit_iou"])
        assert record["speed_withheld"] == withheld
        assert (record["render_rays_per_s"] is None) == (withheld is not None)
        assert (record["common_vs_true_distance_mae"] is None) == (withheld is not None)
    # every round's speed of a point that has one, its median the speed; the CSV gives
    # their range, the section the protocol and the largest spread of a point's rounds
    rounds = bench.SIZES["quick"]["speed_rounds"]
    spreads = []
    for record, row in zip(records, rows):
        timed = record[SPEED_ROUNDS]
        assert (timed is None) == (record["render_rays_per_s"] is None)
        assert SPEED_ROUNDS not in row
        if timed is not None:
            assert len(timed) == rounds and record["render_rays_per_s"] == pytest.approx(
                sum(timed) / rounds)                # the median of two rounds
            assert (float(row["render_rays_per_s_min"]), float(row["render_rays_per_s_max"])
                    ) == (min(timed), max(timed))
            spreads.append((max(timed) - min(timed)) / record["render_rays_per_s"])
    assert f"Render speed: {rounds} rounds, each rendering every point once in turn" in text
    assert (f"at most {percent(max(spreads))} here" if spreads
            else "not measured here, as no point has a speed") in text
    compared = [r for r in records if r["speed_withheld"] is None]
    if compared:
        assert len({r["common_vs_true_compared_rays"] for r in compared}) == 1
        offered, dropped = read_presets(presets)
        assert set(offered) | set(dropped) == set(PRESET_NAMES) and "accurate" in offered
        assert "\nDropped: " in text    # which, if any: the third run above timed anew
    else:         # the quick size's small networks (hit IoU 0.0-0.7 here) predict no hits
        assert not presets.exists() and "presets n/a (no sweep point predicts hits" in printed
        assert "Presets: n/a, no sweep point predicts hits" in text


def test_a_point_trains_again_unless_its_record_and_model_match(tmp_path):
    from vdnif_addon.studies import bench

    size, point = bench.SIZES["quick"], dict(bench.SIZES["quick"]["base"])
    model, path = tmp_path / "point-0.vdnif", tmp_path / "point-0.json"
    record = {"key": bench.point_key(size, point), "steps": 300, "converged": True}
    path.write_text(json.dumps(record))
    assert bench.finished_point(path, model, size, point) is None       # no model beside it
    model.write_bytes(b"model")
    assert bench.finished_point(path, model, size, point) == record
    assert bench.finished_point(path, model, size, dict(point, width=32)) is None
    other = dict(size, convergence=dict(size["convergence"], max_steps=900))
    assert bench.finished_point(path, model, other, point) is None     # another rule
    for text in ("{", "[]", json.dumps(dict(record, key=None))):
        path.write_text(text)
        assert bench.finished_point(path, model, size, point) is None
    assert bench.finished_point(tmp_path / "missing.json", model, size, point) is None


def test_sweep_compares_and_plots_only_points_that_predict_hits(tmp_path):
    """Three sweep points on the same rays: two predict hits (one predicts fewer), one does
    not. The two are compared over the pixels both hit; the third has no speed, no
    common-set error and no say in the presets. The speeds are medians of timing rounds,
    whose ranges and spreads the outputs give."""
    from test_metrics import image, one_material_mesh

    from vdnif_addon.inference.evaluation import compare_both, speed_figures
    from vdnif_addon.studies import bench, bench_report

    mesh = one_material_mesh()
    reference = image(["##########"] * 2)
    few = image(["#########."] * 2, distance=1.1)         # IoU 0.9, off by 0.1
    many = image(["##########"] * 2, distance=1.05)       # IoU 1, off by 0.05 ...
    many.distance[[9, 19]] += 0.3                         # ... and 0.35 where "few" misses
    none = image(["#........."] * 2)                      # IoU 0.1
    rows, runs = [], []
    for number, (predicted, rounds) in enumerate(((few, [2900.0, 3150.0, 3000.0]),
                                                  (many, [1000.0, 990.0, 1010.0]),
                                                  (none, [9000.0, 9000.0, 9000.0]))):
        metrics = compare_both(predicted, reference, reference, mesh, 0.1)
        timings, withheld = speed_figures({"render_rays_per_s": rounds[0]}, metrics["vs_true"])
        report = dict(metrics, timings=dict(timings, train_s=10.0 * (number + 1)),
                      speed_withheld=withheld, model_bytes=1000)
        rows.append(bench._row(dict(bench.SIZES["quick"]["base"], width=32 * (number + 1),
                                    steps=400 + 100 * number, converged=number != 1), report,
                               rounds=None if withheld else rounds))
        runs.append(({"predicted": predicted, "true": reference, "embedded": reference}, 0.1))
    bench._add_common(rows, runs, mesh)
    assert [r["render_rays_per_s"] for r in rows] == [3000.0, 1000.0, None]
    assert [r["common_vs_true_compared_rays"] for r in rows] == [18, 18, None]
    assert rows[1]["vs_true_distance_mae"] == pytest.approx(0.08)      # its own pixels
    assert [r[PRESET_ERROR] for r in rows[:2]] == pytest.approx([0.1, 0.05])
    assert rows[2][PRESET_ERROR] is None
    # two points to compare: too few for three distinct presets
    with pytest.raises(VDNIFError, match="no third for balanced; widen the sweep") as refused:
        derive_presets(rows, PRESET_ERROR)
    assert [r[SPEED_ROUNDS] for r in rows] == [[2900.0, 3150.0, 3000.0],
                                               [1000.0, 990.0, 1010.0], None]
    bench_report.write_outputs(tmp_path, rows)
    assert (tmp_path / "pareto.png").stat().st_size > 10_000
    # bench.json keeps every round; bench.csv, flat, their slowest and fastest
    assert json.loads((tmp_path / "bench.json").read_text())[0][SPEED_ROUNDS] == [
        2900.0, 3150.0, 3000.0]
    flat = list(csv.DictReader(open(tmp_path / "bench.csv")))
    assert SPEED_ROUNDS not in flat[0] and [(r["render_rays_per_s_min"],
                                             r["render_rays_per_s_max"]) for r in flat] == [
        ("2900.0", "3150.0"), ("990.0", "1010.0"), ("", "")]
    text = "\n".join(bench_report.sweep_markdown(rows, str(refused.value),
                                                 bench.SIZES["quick"], "cmd", tmp_path, None))
    assert "have a speed, 2 of 3 here" in text and "the 18 pixels" in text
    assert "Presets: n/a, the sweep has two points that predict hits" in text
    # the protocol and its noise: spreads (3150 - 2900) / 3000 = 8.33 % and 20 / 1000 = 2 %
    assert ("Render speed: 2 rounds, each rendering every point once in turn (the rounds "
            "interleaved" in text)
    assert ("A point's speed is the median of its rounds; their spread, (max - min) / median, "
            "is the timing's noise on it: at most 8.33 % here (R16 L2 T12 F3 W32 S400), "
            "5.17 % on the median point" in text)
    assert "| 3,000 (2,900-3,150) | 8.33 % | 1,000 |" in text
    # compared round by round: the two points' ratios 2.9, 3.18, 2.97 spread by 9.49 %
    assert ("one differs measurably from the other when it is faster in every round (by "
            "chance one time in 4 with 2 rounds). The ratio of two points' speeds spreads "
            "over the rounds by 9.49 % for the median pair" in text)
    # neither machine, threads nor load recorded (rows without provenance): said so
    assert "torch's CPU threads not recorded" in text
    assert "recorded neither machine nor load: their training times do not compare" in text
    assert "| 10.0 | 3,000 (2,900-3,150)" in text
    # one timed point has no pair: its noise is said, no ratio's spread
    alone = bench_report.timing_text(rows[:1], 3)
    assert "at most 8.33 % here" in alone and "ratio" not in alone and "nan" not in alone
    assert "| 1,000 (990-1,010) | 2 % | 1,000 |" in text and "| n/a | n/a | 1,000 |" in text
    # a balanced nearer the two-point front than any other, but slower than accurate:
    # dropped, and the section says why
    points = rows + [dict(rows[1], width=96, render_rays_per_s=900.0,
                          **{SPEED_ROUNDS: [880.0, 900.0, 920.0]})]
    assert [pick_presets(points, PRESET_ERROR)[name]["width"] for name in PRESET_NAMES] == [
        32, 96, 64]
    presets, dropped = derive_presets(points, PRESET_ERROR)
    assert list(presets) == ["fast", "accurate"]
    text = "\n".join(bench_report.sweep_markdown(rows, (presets, dropped),
                                                 bench.SIZES["quick"], "cmd", tmp_path, None))
    assert "| fast | 16 | 2 | 12 | 3 | 32 | 400 | 0.1 | 3,000 (2,900-3,150) |" in text
    assert ("Dropped: balanced, measured no faster than Accurate: faster in 0 of 3 timing "
            "rounds, 0.88-0.91x round by round." in text) and "| balanced |" not in text
    text = "\n".join(bench_report.sweep_markdown(rows, (pick_presets(points, PRESET_ERROR), {}),
                                                 bench.SIZES["quick"], "cmd", tmp_path, None))
    assert "| balanced | 16 | 2 | 12 | 3 | 96 | 500 | 0.05 | 900 (880-920) |" in text
    assert ("Dropped: none, each preset was faster in every round than the next more "
            "accurate one." in text)
    # a sweep where no point has a speed states that the noise is not measured
    text = "\n".join(bench_report.sweep_markdown(rows[2:], bench_report.NO_PRESETS,
                                                 bench.SIZES["quick"], "cmd", tmp_path, None))
    assert "timing's noise on it: not measured here, as no point has a speed." in text


def test_a_points_speed_is_the_median_of_its_rounds_and_its_errors_the_first_rounds(
        tmp_path, monkeypatch):
    """One render times a point only roughly: every point renders once per round and its
    speed is the median of its rounds. The renders are stand-ins whose speeds are given, the
    rounds interleaved (point 1, point 2, point 1, ...)."""
    from types import SimpleNamespace

    from vdnif_addon.studies import bench

    size = dict(bench.SIZES["quick"], speed_rounds=5)
    points = [dict(resolution=16, width=32), dict(resolution=12, width=64)]
    given = {0: [9.0, 1.0, 4.0, 2.0, 3.0], 1: [None] * 5}      # point 2 predicts no hits
    calls = []

    def evaluate_file(obj, evaluated, model, width, height, device):
        number = int(model.stem.split("-")[1])
        speed = given[number][sum(1 for c in calls if c == number)]
        calls.append(number)
        metrics = {key: 0.1 * len(calls) for key in bench.METRICS}
        report = {"vs_true": metrics, "vs_embedded": metrics, "speed_withheld": None,
                  "model_bytes": 1, "timings": {"train_s": 1.0, "render_rays_per_s": speed}}
        return report, [len(calls)]

    monkeypatch.setattr(bench, "evaluate_file", evaluate_file)
    pose_sets, follows = [], []

    def evaluation_poses(obj, resolution, spec, count, pose_set, follow):
        pose_sets.append(pose_set)
        follows.append((resolution, follow))
        return SimpleNamespace(grid=SimpleNamespace(voxel_size=0.1), mesh=None)

    monkeypatch.setattr(bench, "evaluation_poses", evaluation_poses)
    # each point's corners follow as its model's did (the stand-in models say how)
    recorded = {"point-0.vdnif": "evaluated surface", "point-1.vdnif": "armature copy"}
    monkeypatch.setattr(bench, "load_model", lambda path: (
        None, SimpleNamespace(corners_follow=recorded[path.name])))
    monkeypatch.setattr(bench, "finished_point", lambda path, model, size, point:
                        {"steps": 10, "converged": True})
    monkeypatch.setattr(bench, "concatenated", lambda views: views)
    common = []
    monkeypatch.setattr(bench, "_add_common", lambda rows, runs, mesh: common.append(runs))
    rows = bench._evaluate_points(None, None, size, points, tmp_path, "cpu")
    assert calls == [0, 1] * 5
    # the presets and the front are choices: made on the development poses alone
    assert pose_sets == [DEVELOPMENT_POSES] * 2
    assert sorted(follows) == [(12, "armature copy"), (16, "evaluated surface")]
    assert rows[0]["render_rays_per_s"] == 3.0 and rows[1]["render_rays_per_s"] is None
    # every round's speed is kept beside the median, none where the speed is withheld
    assert rows[0][SPEED_ROUNDS] == [9.0, 1.0, 4.0, 2.0, 3.0] and rows[1][SPEED_ROUNDS] is None
    # the errors and the views compared on the common pixels are the first round's
    assert rows[0]["vs_true_distance_mae"] == pytest.approx(0.1)
    assert rows[1]["vs_true_distance_mae"] == pytest.approx(0.2)
    assert common == [[([1], 0.1), ([2], 0.1)]]
