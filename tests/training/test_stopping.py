"""The stopping rule (``training.stopping``) on hand-made validations, and inside training."""

import pytest
from test_train import header, sphere_shards

from vdnif_addon.errors import VDNIFError
from vdnif_addon.settings import NetworkConfig, TrainConfig
from vdnif_addon.training.stopping import StoppingRule, watched
from vdnif_addon.training.train import train


def validations(errors):
    """(step, validation) every 100 steps whose held-out figures are ``errors``: a list of
    (occlusion error, distance MAE in voxels, normal error) per validation."""
    return [(100 * (i + 1), {"occlusion_accuracy": 1 - occlusion, "distance_mae_voxels": distance,
                             "normal_error_deg": normal, "segments": 1000.0})
            for i, (occlusion, distance, normal) in enumerate(errors)]


def feed(rule, records):
    for step, validation in records:
        if rule.update(step, validation):
            return step
    return None


def test_stops_after_patience_validations_without_a_real_gain():
    rule = StoppingRule(patience=3, min_gain=0.02)
    # 300: distance improves by 10 %; then 1 % gains only (below 2 %), normal flat: the
    # third validation without a real gain (600) converges
    errors = [(0.1, 1.0, 20.0), (0.1, 0.95, 20.0), (0.1, 0.855, 20.0), (0.1, 0.85, 20.0),
              (0.099, 0.849, 19.9), (0.0995, 0.846, 20.1), (0.05, 0.5, 5.0)]
    assert feed(rule, validations(errors)) == 600 == rule.converged_at
    assert rule.marks["distance_mae_voxels"] == pytest.approx(0.855)


def test_a_slow_decline_counts_once_it_adds_up():
    rule = StoppingRule(patience=3, min_gain=0.02)
    # 1 % less every validation: each gain alone is below 2 %, three add up to more, so the
    # mark moves every third validation and the rule never sees 3 in a row without a gain
    errors = [(0.1, 0.99 ** i, 10.0) for i in range(40)]
    assert feed(rule, validations(errors)) is None and rule.converged_at is None
    # a figure that only rises never counts as a gain
    rule = StoppingRule(patience=2, min_gain=0.02)
    assert feed(rule, validations([(0.1, 1.0 + i, 10.0) for i in range(5)])) == 300


def test_no_validation_or_no_patience_never_stops():
    rule = StoppingRule(patience=1, min_gain=0.02)
    assert not any(rule.update(step, None) for step in (100, 200, 300))
    rule = StoppingRule(patience=0, min_gain=0.02)
    assert feed(rule, validations([(0.1, 1.0, 10.0)] * 10)) is None
    figures = watched({"occlusion_accuracy": 0.9, "material_accuracy": 0.75,
                       "distance_mae_voxels": 0.2, "loss/occlusion": 0.3})
    assert figures == pytest.approx({"occlusion_error": 0.1, "material_error": 0.25,
                                     "distance_mae_voxels": 0.2})


def test_training_ends_where_the_rule_says():
    """A gain of 100 % is impossible: the first validation sets the marks, the next one
    without a gain ends training (patience 1), at the second validation's step."""
    config = TrainConfig(steps=200, batch_size=64, log_interval=20, stop_patience=1,
                         stop_min_gain=1.0, device="cpu")
    small = NetworkConfig(levels=2, log2_table_size=10, width=16, depth=1)
    result = train(sphere_shards(), header(), config, small)
    assert result.status == "converged" and result.steps == 40
    assert [r["step"] for r in result.history] == [20, 40]
    result = train(sphere_shards(), header(), TrainConfig(
        steps=60, batch_size=64, log_interval=20, stop_patience=0, device="cpu"), small)
    assert result.status == "completed" and result.steps == 60


@pytest.mark.parametrize("field, value", [("stop_patience", -1), ("stop_min_gain", 1.5),
                                          ("stop_min_gain", float("nan"))])
def test_absurd_rule_settings_are_refused(field, value):
    with pytest.raises(VDNIFError, match=field):
        TrainConfig(**{field: value})
