import contextlib
import dataclasses
import json
import math
import os
import pathlib
import socket
import threading

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp
from dataset_headers import header_dict

from vdnif_addon import threads
from vdnif_addon.errors import VDNIFError
from vdnif_addon.model import encoding
from vdnif_addon.model.encoding import HashGrid
from vdnif_addon.model.model_file import load_model
from vdnif_addon.model.network import IntersectionNetwork, readout
from vdnif_addon.model.variants import variant_config
from vdnif_addon.settings import Heads, NetworkConfig, TrainConfig
from vdnif_addon.training import train as training
from vdnif_addon.training.data import load_segments
from vdnif_addon.training.fit import fit_model
from vdnif_addon.training.header import DatasetHeader
from vdnif_addon.training.losses import (
    FixedWeighting,
    UncertaintyWeighting,
    make_weighting,
    task_losses,
)
from vdnif_addon.training.train import train
from vdnif_addon.training.validation import (
    CANDIDATE_THRESHOLDS,
    calibrate_candidate_threshold,
    calibrate_threshold,
    evaluate,
    head_outputs,
)

SMALL = {"levels": 2, "base_resolution": 16, "log2_table_size": 12, "width": 32, "depth": 2}
GOLDEN = pathlib.Path(__file__).resolve().parents[1] / "golden"


def sphere_shards(n=256, shards=2, poses=4, voxel_size=0.125, resolution=8, seed=0, radius=0.25):
    """Segments of about one voxel near a sphere (normalized center 0.5), with analytic targets.

    Rest units are normalized units times ``voxel_size * resolution``; albedo is the hit
    position, material 1 on the upper half.
    """
    rng = np.random.default_rng(seed)
    center = np.full(3, 0.5)
    start = rng.normal(size=(n, 3))
    p0 = center + start / np.linalg.norm(start, axis=1, keepdims=True) * (
        radius + rng.uniform(-0.08, 0.08, (n, 1))
    )
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = rng.uniform(0.3, 1.0, n) / resolution
    oc = p0 - center
    b, c = (oc * d).sum(1), (oc**2).sum(1) - radius**2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(-b - root >= 0, -b - root, -b + root)
    hit = (disc >= 0) & (t >= 0) & (t <= length)
    point = p0 + d * t[:, None]
    rest_len = length * voxel_size * resolution
    data = {
        "p0": p0,
        "p1": p0 + d * length[:, None],
        "seg_len": rest_len * rng.uniform(0.8, 1.2, n),
        "rest_len": rest_len,
        "hit": hit.astype(np.uint8),
        "hit_frac": np.where(hit, t / length, 0.0),
        "normal": np.where(hit[:, None], (point - center) / radius, 0.0),
        "albedo": np.where(hit[:, None], np.clip(point, 0.0, 1.0), 0.0),
        "material": np.where(hit & (point[:, 2] > 0.5), 1, 0).astype(np.int16),
        "pose": rng.integers(0, poses, n).astype(np.int32),
        "ray": np.arange(n, dtype=np.int32),      # one segment per ray
        "t0": rng.uniform(0.0, 2.0, n),
    }
    data = {
        key: value.astype(np.float32) if value.dtype == np.float64 else value
        for key, value in data.items()
    }
    return [{key: value[i::shards] for key, value in data.items()} for i in range(shards)]


def header(voxel_size=0.125, albedo=True, materials=2):
    return DatasetHeader.from_dict(
        header_dict(voxel_size=voxel_size, albedo=albedo, materials=materials), "test header")


def finite_module(module):
    return all(torch.isfinite(p).all() for p in module.parameters())


# --------------------------------------------------------------------------- losses


def test_all_miss_batch_gives_zero_hit_losses_and_finite_gradients():
    n = 32
    outputs = {
        "occlusion": torch.randn(n, requires_grad=True),
        "distance": torch.rand(n, requires_grad=True),
        "normal": torch.zeros(n, 3, requires_grad=True),  # degenerate prediction as well
        "albedo": torch.rand(n, 3, requires_grad=True),
        "material": torch.randn(n, 4, requires_grad=True),
    }
    batch = {
        "hit": torch.zeros(n, dtype=torch.bool),
        "hit_frac": torch.zeros(n),
        "rest_len": torch.zeros(n),
        "normal": torch.zeros(n, 3),
        "albedo": torch.zeros(n, 3),
        "material": torch.full((n,), -1),
    }
    losses = task_losses(outputs, batch, "log1p-fraction")
    assert losses["occlusion"] > 0
    assert all(losses[task] == 0 for task in ("distance", "normal", "albedo", "material"))
    UncertaintyWeighting(list(losses))(losses).backward()
    assert all(torch.isfinite(value.grad).all() for value in outputs.values())


def test_distance_targets_follow_the_mode():
    batch = {
        "hit": torch.tensor([True, True, False]),
        "hit_frac": torch.tensor([0.5, 0.0, 0.0]),
        "rest_len": torch.tensor([4.0, 4.0, 4.0]),
        "normal": torch.tensor([[0.0, 0.0, 1.0]] * 3),
    }
    outputs = {
        "occlusion": torch.zeros(3),
        "distance": torch.tensor([0.0, 0.0, 9.0]),
        "normal": torch.tensor([[0.0, 0.0, 1.0]] * 3),
    }
    torch.testing.assert_close(
        task_losses(outputs, batch, "fraction")["distance"], torch.tensor(0.125)
    )
    # log1p(t/l): the output is log1p of the hit's fraction of its segment, its error taken
    # in that fraction (expm1(0) = 0 against 0.5)
    torch.testing.assert_close(
        task_losses(outputs, batch, "log1p-fraction")["distance"], torch.tensor(0.5 ** 2 / 2))
    # log1p(d/h), the paper's written form: its error in log space, d = 0.5 * 4 = 2 voxel
    # edges of 1 against an output of 0 (the first hit) and 0 against 0 (the second)
    torch.testing.assert_close(
        task_losses(outputs, batch, "log-distance", voxel_size=1.0)["distance"],
        torch.tensor(math.log(3.0) ** 2 / 2))
    with pytest.raises(VDNIFError, match="voxel size"):
        task_losses(outputs, batch, "log-distance")
    exact = dict(outputs, distance=torch.tensor([math.log1p(0.5), 0.0, 9.0]))
    assert task_losses(exact, batch, "log1p-fraction")["distance"] < 1e-12
    assert task_losses(outputs, batch, "fraction")["normal"] == 0


def test_log_distance_error_weighs_far_and_near_hits_alike():
    """An output 0.02 off in t/l costs the same near the segment's start and near its end,
    where the error in log space would cost about a quarter as much; a miss's untrained
    output, however large, leaves finite gradients."""
    def loss(fraction, output_fraction):
        batch = {"hit": torch.tensor([True, False]), "hit_frac": torch.tensor([fraction, 0.0]),
                 "rest_len": torch.ones(2), "normal": torch.tensor([[0.0, 0.0, 1.0]] * 2)}
        distance = torch.tensor([math.log1p(output_fraction), 500.0], requires_grad=True)
        outputs = {"occlusion": torch.zeros(2), "distance": distance,
                   "normal": torch.tensor([[0.0, 0.0, 1.0]] * 2)}
        value = task_losses(outputs, batch, "log1p-fraction")["distance"]
        value.backward()
        assert torch.isfinite(distance.grad).all()
        return value.item()

    near, far = loss(0.05, 0.07), loss(0.95, 0.97)
    assert near == pytest.approx(far, rel=1e-4) and near == pytest.approx(0.02 ** 2, rel=1e-3)


def test_uncertainty_weighting_equal_start_is_the_plain_sum_plus_its_log_variances():
    """start="equal": every task weighs 1 at the start, as in the fixed weighting, and the
    log-variances start at log 0.5 (regression) and 0 (classification)."""
    losses = {"occlusion": torch.tensor(0.7), "distance": torch.tensor(0.2),
              "normal": torch.tensor(0.1), "albedo": torch.tensor(0.3),
              "material": torch.tensor(1.5)}
    weighting = make_weighting("uncertainty", list(losses), "equal")
    s = weighting.log_variances()
    assert s["occlusion"] == s["material"] == 0.0
    for task in ("distance", "normal", "albedo"):
        assert s[task] == pytest.approx(math.log(0.5), abs=1e-6)
    plain = FixedWeighting(list(losses))(losses)
    torch.testing.assert_close(weighting(losses), plain + 0.5 * 3 * math.log(0.5))
    zero = make_weighting("uncertainty", list(losses), "zero").log_variances()
    assert zero == dict.fromkeys(losses, 0.0)
    assert make_weighting("uncertainty", list(losses)).log_variances() == s  # the default
    with pytest.raises(VDNIFError, match="weighting_start"):
        TrainConfig(weighting_start="equals")


def test_uncertainty_weighting_formula_and_bounds():
    losses = {
        "occlusion": torch.tensor(0.7),
        "distance": torch.tensor(0.2),
        "material": torch.tensor(1.5),
    }
    weighting = UncertaintyWeighting(list(losses), start="zero")
    assert weighting.log_variances() == {"occlusion": 0.0, "distance": 0.0, "material": 0.0}
    torch.testing.assert_close(weighting(losses), torch.tensor(0.7 + 0.5 * 0.2 + 1.5))
    with torch.no_grad():
        weighting.raw.copy_(torch.tensor([1.0, -2.0, 1e6]))
    s = torch.tensor(list(weighting.log_variances().values()))
    assert s.abs().max() <= 6 and s[2] > 5.9
    expected = (
        math.exp(-s[0]) * 0.7
        + 0.5 * s[0]
        + 0.5 * math.exp(-s[1]) * 0.2
        + 0.5 * s[1]
        + math.exp(-s[2]) * 1.5
        + 0.5 * s[2]
    )
    torch.testing.assert_close(weighting(losses), torch.tensor(float(expected)))
    torch.testing.assert_close(FixedWeighting(list(losses))(losses), torch.tensor(2.4))
    with pytest.raises(VDNIFError, match="weighting"):
        make_weighting("learned", ["occlusion"])


# --------------------------------------------------------------------------- training


def test_overfits_every_head():
    shards = sphere_shards(n=256, poses=1)
    config = TrainConfig(steps=500, batch_size=256, val_fraction=0.0, log_interval=50,
                         device="cpu")
    result = train(shards, header(), config, NetworkConfig(**SMALL))
    first, last = result.history[0]["losses"], result.history[-1]["losses"]
    assert set(first) == {"occlusion", "distance", "normal", "albedo", "material"}
    for task in first:
        assert last[task] < 0.1 * first[task], task
    metrics = evaluate(result.network, load_segments(shards, result.network_config.heads), 0.125)
    assert metrics["hits"] > 30
    assert metrics["occlusion_accuracy"] >= 0.99
    assert metrics["distance_mae_voxels"] < 0.05
    assert metrics["normal_error_deg"] < 5
    assert metrics["loss/albedo"] < 0.02
    assert metrics["material_accuracy"] >= 0.99
    assert result.status == "completed" and result.steps == 500 and result.validation is None


def test_point_fields_learn_the_albedo_and_normal_of_the_hit_point():
    """``albedo_mode`` and ``normal_mode`` "hit": the fields' tables train at the grid's rate
    beside the encoder's, and the fields learn the sphere's albedo (its hit position) and
    normal at the reference's hit; read at the hit the network places, they stay close."""
    shards = sphere_shards(n=256, poses=1)
    config = TrainConfig(steps=500, batch_size=256, val_fraction=0.0, log_interval=50,
                         device="cpu")
    network_config = NetworkConfig(**SMALL, albedo_mode="hit", normal_mode="hit")
    network = IntersectionNetwork(dataclasses.replace(network_config, heads=Heads(albedo=True)))
    objective = training.Objective(network, make_weighting("fixed", list(network.head_sizes)),
                                   1.0)
    groups = training._optimizer(objective, config)[0].param_groups
    grid_group = next(g for g in groups if g["lr"] == config.lr_grid)
    assert {id(p) for p in grid_group["params"]} == {
        id(network.encoder.grid.table), id(network.albedo_field.grid.table),
        id(network.normal_field.grid.table)}
    result = train(shards, header(), config, network_config)
    assert set(result.network.point_fields()) == {"albedo", "normal"}
    first, last = result.history[0]["losses"], result.history[-1]["losses"]
    assert last["albedo"] < 0.1 * first["albedo"]
    assert last["normal"] < 0.1 * first["normal"]
    data = load_segments(shards, result.network_config.heads)
    metrics = evaluate(result.network, data, 0.125)
    assert metrics["loss/albedo"] < 0.02
    assert metrics["normal_error_deg"] < 5
    hit = data["hit"]
    predicted = result.network.predict(data["p0"][hit], data["p1"][hit], data["rest_len"][hit],
                                       0.125)
    assert (predicted["albedo"] - data["albedo"][hit]).abs().mean() < 0.03
    cos = (predicted["normal"] * data["normal"][hit]).sum(1).clamp(-1, 1)
    assert torch.rad2deg(torch.arccos(cos)).mean() < 5


def random_batch(n, hit_share, materials=1):
    """A training batch of ``n`` random rows, ``hit_share`` of them hits, drawn from torch's
    generator."""
    hit = torch.rand(n) < hit_share
    return {"p0": torch.rand(n, 3), "p1": torch.rand(n, 3), "hit": hit,
            "hit_frac": torch.where(hit, torch.rand(n), 0.0),
            "rest_len": 0.2 + torch.rand(n),
            "normal": torch.nn.functional.normalize(torch.randn(n, 3), dim=1),
            "albedo": torch.rand(n, 3), "material": torch.randint(materials, (n,))}


def bfloat16_steps(network, batch, steps):
    """``network`` after ``steps`` training steps on ``batch`` with its MLPs in bfloat16
    (uncertainty weighting, voxel size 0.5)."""
    objective = training.Objective(network, make_weighting("uncertainty",
                                                           list(network.head_sizes)),
                                   0.5, precision="bfloat16")
    step = training.TrainingStep(objective, TrainConfig(steps=steps, log_interval=steps))
    for _ in range(steps):
        step(batch)
    return network


def test_bfloat16_steps_multiply_the_mlps_in_it_and_keep_the_rest_float32():
    """An objective in bfloat16 runs every Linear layer (the trunk's and the fields') in
    bfloat16, forward and backward, while its losses, the weights' gradients and the hash
    tables' stay float32; the loss is float32's within bfloat16's rounding, and a step's
    gradients point as float32's do. A precision name neither knows is refused."""
    torch.manual_seed(0)
    network_config = NetworkConfig(**SMALL, normal_mode="hit", albedo_mode="hit")
    batch = random_batch(2000, 0.3)
    results = {}
    for precision in ("float32", "bfloat16"):
        torch.manual_seed(1)
        network = IntersectionNetwork(dataclasses.replace(network_config,
                                                          heads=Heads(albedo=True)))
        objective = training.Objective(network, make_weighting("fixed",
                                                               list(network.head_sizes)),
                                       0.5, precision=precision)
        dtypes = []
        hooks = [module.register_forward_hook(
            lambda module, inputs, output: dtypes.append(output.dtype))
            for module in network.modules() if isinstance(module, torch.nn.Linear)]
        total, losses = objective(batch)
        for hook in hooks:
            hook.remove()
        total.backward()
        assert total.dtype == losses.dtype == torch.float32
        assert all(p.grad.dtype == torch.float32 for p in network.parameters()
                   if p.grad is not None)
        assert set(dtypes) == {torch.bfloat16 if precision == "bfloat16" else torch.float32}
        assert len(dtypes) == sum(isinstance(m, torch.nn.Linear) for m in network.modules())
        results[precision] = (float(total.detach()), {name: p.grad.clone() for name, p in
                                             network.named_parameters() if p.grad is not None})
    (loss32, grads32), (loss16, grads16) = results["float32"], results["bfloat16"]
    assert loss16 == pytest.approx(loss32, rel=0.02) and loss16 != loss32
    for name, grad in grads32.items():
        cos = torch.nn.functional.cosine_similarity(grad.flatten(), grads16[name].flatten(),
                                                    dim=0)
        assert cos > 0.95, name
    with pytest.raises(VDNIFError, match="float32 or bfloat16"):
        training.Objective(network, make_weighting("fixed", list(network.head_sizes)), 0.5,
                           precision="auto")
    with pytest.raises(VDNIFError, match="precision"):
        TrainConfig(precision="float16")


def test_bfloat16_features_from_the_kernel_train_as_autocast_rounds_them(monkeypatch):
    """In bfloat16 the grids hand their features on in it (``encoding.feature_dtype``) and
    take their gradient as it comes: steps give the same weights bit for bit as float32
    features that autocast rounds for the first layer, and their gradient converted back."""
    torch.manual_seed(0)
    network_config = NetworkConfig(**SMALL, normal_mode="hit", albedo_mode="hit",
                                   heads=Heads(albedo=True))
    batch = random_batch(3000, 0.4)

    def trained(handed_on):
        monkeypatch.setattr(encoding, "feature_dtype", handed_on)
        torch.manual_seed(1)
        network = IntersectionNetwork(network_config)
        seen = []
        hooks = [grid.register_forward_hook(lambda module, inputs, output:
                                            seen.append(output.dtype))
                 for grid in network.modules() if isinstance(grid, HashGrid)]
        bfloat16_steps(network, batch, 4)
        for hook in hooks:
            hook.remove()
        return set(seen), {name: p.detach().clone() for name, p in network.named_parameters()}

    original = encoding.feature_dtype
    grids_dtypes, weights = trained(original)
    float_dtypes, expected = trained(lambda device: torch.float32)
    assert grids_dtypes == {torch.bfloat16} and float_dtypes == {torch.float32}
    for name, value in expected.items():
        assert torch.equal(weights[name], value), name


def test_the_fields_learn_at_jittered_hits_on_rows_that_cover_the_hits(monkeypatch):
    """In training the point fields are read at the reference's hit moved along the segment
    by N(0, ``field_jitter`` voxels), from the objective's own seeded generator, on
    ``field_rows`` rows that hold every hit of the batch; in eval mode at the hit itself.
    The distance loss keeps the unmoved hit."""
    torch.manual_seed(0)
    network = IntersectionNetwork(NetworkConfig(**SMALL, normal_mode="hit"))
    n, voxel, jitter = 4000, 0.5, 0.1
    hit = torch.rand(n) < 0.2
    batch = {"p0": torch.rand(n, 3), "p1": torch.rand(n, 3), "hit": hit,
             "hit_frac": torch.where(hit, torch.rand(n), 0.0),
             "rest_len": 0.2 + torch.rand(n), "normal": torch.randn(n, 3),
             "albedo": torch.rand(n, 3), "material": torch.zeros(n, dtype=torch.int64)}
    rows = training.field_rows(hit, n)
    share = float(hit.float().mean())
    assert n * share + 1 < rows <= n * share + 6 * math.sqrt(n * share * (1 - share)) + 2
    assert training.field_rows(torch.zeros(10, dtype=torch.bool), 64) == 1
    assert training.field_rows(torch.ones(10, dtype=torch.bool), 64) == 64
    seen = []
    forward = network.forward
    monkeypatch.setattr(network, "forward", lambda p0, p1, at, rows: (
        seen.append((at, rows)), forward(p0, p1, at, rows))[1])

    def objective(seed):
        return training.Objective(network, make_weighting("fixed", list(network.head_sizes)),
                                  voxel, jitter, seed, rows)

    first = objective(3)
    first(batch)
    at, chosen = seen[-1]
    assert len(chosen) == rows and set(hit.nonzero().squeeze(1).tolist()) <= set(chosen.tolist())
    shift = (at - batch["hit_frac"]) * batch["rest_len"] / voxel      # in voxels
    assert abs(float(shift.mean())) < 0.01 and 0.09 < float(shift.std()) < 0.11
    objective(3)(batch)
    assert torch.equal(seen[-1][0], at)                 # the same seed draws the same shifts
    objective(4)(batch)
    assert not torch.equal(seen[-1][0], at)
    first.eval()
    total, losses = first(batch)
    assert torch.equal(seen[-1][0], batch["hit_frac"])  # eval: the hit itself
    with torch.no_grad():
        outputs = forward(batch["p0"], batch["p1"], batch["hit_frac"])
    expected = task_losses(outputs, batch, network.config.distance_mode, voxel)
    torch.testing.assert_close(losses, torch.stack(list(expected.values())))


@pytest.mark.parametrize("share", [0.0, 0.01, 0.3, 1.0])
def test_hits_first_is_the_stable_sort_of_the_misses_flags(share):
    """The fields' rows: every hit, then every miss, each in row order, as the stable sort
    of the misses' flags orders them (the oracle)."""
    generator = torch.Generator().manual_seed(7)
    for n in (1, 2, 37, 16384):
        hit = torch.rand(n, generator=generator) < share
        expected = torch.argsort((~hit).to(torch.int8), stable=True)
        assert torch.equal(training.hits_first(hit), expected)


def _all_miss(shards):
    for shard in shards:
        shard["hit"][:] = 0
        for key in ("hit_frac", "normal", "albedo"):
            shard[key][:] = 0
    return shards


def _zero_distances(shards):
    for shard in shards:
        shard["hit_frac"][: len(shard["hit_frac"]) // 2] = 0.0
    return shards


@pytest.mark.parametrize(
    "voxel_size, variant, heads, prepare",
    [
        (
            1e-3,
            "proposed",
            (False, 1),
            _zero_distances,
        ),  # tiny object, zero distances, one material
        (1e3, "lsnif", (True, 3), _zero_distances),  # huge object, sigmoid distance, fixed weights
        (1.0, "proposed", (True, 2), _all_miss),  # every batch without a hit
    ],
)
def test_500_steps_stay_finite(voxel_size, variant, heads, prepare):
    shards = prepare(sphere_shards(n=256, voxel_size=voxel_size, seed=4))
    settings = variant_config(
        variant, **SMALL, steps=500, batch_size=64, log_interval=100, device="cpu", lr_mlp=1e-2
    )
    result = train(shards, header(voxel_size, *heads), settings.train, settings.network)
    assert result.status == "completed" and result.steps == 500
    assert finite_module(result.network)
    for record in result.history:
        assert math.isfinite(record["total"]) and all(
            math.isfinite(v) for v in record["losses"].values()
        )
        assert all(math.isfinite(s) for s in record["log_variances"].values())
    assert ("material" in result.history[-1]["losses"]) == (heads[1] > 1)
    assert all(math.isfinite(v) for v in result.validation.values())


def test_uncertainty_weights_learn_at_their_own_rate():
    """The log-variances s are an optimizer group of their own at ``lr_weighting``; the
    rest of the objective keeps the grid's and the MLP's rates. Trained on the same data,
    s moves about ten times as far at 1e-2 as at the MLP's 1e-3 (Adam steps by about the
    rate while the gradient keeps its sign): the weighting reaches the weights it learns."""
    moved = {}
    for rate in (1e-3, 1e-2):
        config = variant_config("proposed", **SMALL, steps=60, batch_size=64, log_interval=60,
                                device="cpu", val_fraction=0.0, lr_weighting=rate)
        objective = training.Objective(IntersectionNetwork(config.network),
                                       make_weighting("uncertainty", ["occlusion", "distance",
                                                                      "normal"]), 1.0)
        optimizer, _ = training._optimizer(objective, config.train)
        rates = sorted(group["lr"] for group in optimizer.param_groups)
        assert rates == sorted([config.train.lr_grid, config.train.lr_mlp, rate])
        weights = [g for g in optimizer.param_groups if g["lr"] == rate and
                   any(p is objective.weighting.raw for p in g["params"])]
        assert len(weights) == 1 and len(weights[0]["params"]) == 1
        result = train(sphere_shards(n=256, poses=4), header(), config.train, config.network)
        start = make_weighting("uncertainty", list(result.history[-1]["log_variances"]),
                               config.train.weighting_start).log_variances()
        moved[rate] = max(abs(s - start[task])
                          for task, s in result.history[-1]["log_variances"].items())
    assert moved[1e-2] > 5 * moved[1e-3] > 0
    fixed = variant_config("deformed", **SMALL, device="cpu")
    objective = training.Objective(IntersectionNetwork(fixed.network),
                                   make_weighting("fixed", ["occlusion"]), 1.0)
    assert len(training._optimizer(objective, fixed.train)[0].param_groups) == 2
    with pytest.raises(VDNIFError, match="lr_weighting"):
        TrainConfig(lr_weighting=0.0)


def test_progress_reports_and_held_out_poses():
    records = []
    config = TrainConfig(steps=40, batch_size=64, val_fraction=0.25, log_interval=20, device="cpu")
    result = train(
        sphere_shards(n=256, poses=8),
        header(),
        config,
        NetworkConfig(**SMALL),
        progress=records.append,
    )
    assert [r["step"] for r in records] == [20, 40]
    record = records[-1]
    assert record["steps"] == 40 and record["samples_per_s"] > 0 and record["eta_s"] == 0
    assert set(record["log_variances"]) == set(record["losses"])
    assert len(result.val_poses) == 2 and record["validation"]["segments"] > 0
    assert result.validation["segments"] == sum(
        np.isin(s["pose"], result.val_poses).sum() for s in sphere_shards(n=256, poses=8)
    )
    assert result.info()["status"] == "completed" and result.is_main


def test_cancel_stops_before_the_next_update():
    cancel = threading.Event()
    config = TrainConfig(steps=1000, batch_size=32, log_interval=10, device="cpu")
    result = train(
        sphere_shards(),
        header(),
        config,
        NetworkConfig(**SMALL),
        progress=lambda _: cancel.set(),
        cancel=cancel,
    )
    assert result.status == "cancelled" and result.steps == 10 and len(result.history) == 1
    assert finite_module(result.network) and not result.network.training


def test_training_follows_the_recorded_loss_curve(tmp_path):
    """The golden run of the proposed variant at today's recipe (tests/golden/make_goldens.py,
    recorded before the core moved into stage packages, in float32): the first 50 steps'
    total and task losses, each within 1e-3 relative."""
    golden = json.loads((GOLDEN / "arm-train.json").read_text())
    settings = dict(golden["settings"])
    variant = settings.pop("variant")
    records = []
    fit_model(GOLDEN / "arm-dataset", variant, tmp_path / "model.vdnif",
              dict(settings, log_interval=1, precision="float32"), progress=records.append)
    assert [r["step"] for r in records] == [g["step"] for g in golden["history"]] == list(
        range(1, 51))
    for record, expected in zip(records, golden["history"]):
        assert record["total"] == pytest.approx(expected["total"], rel=1e-3), record["step"]
        assert record["losses"].keys() == expected["losses"].keys()
        for task, value in expected["losses"].items():
            assert record["losses"][task] == pytest.approx(value, rel=1e-3), (record["step"], task)
    network, metadata = load_model(tmp_path / "model.vdnif")
    assert network.thresholds == metadata.thresholds
    assert metadata.training.steps == 50 and metadata.object == "Arm"


def test_same_seed_gives_identical_weights():
    def weights(seed):
        config = TrainConfig(steps=30, batch_size=64, seed=seed, log_interval=30, device="cpu")
        result = train(sphere_shards(), header(), config, NetworkConfig(**SMALL))
        return result.network.state_dict()

    first, second, other = weights(7), weights(7), weights(8)
    assert all(torch.equal(first[key], second[key]) for key in first)
    assert not all(torch.equal(first[key], other[key]) for key in first)


def counted_header(occupied):
    data = header_dict()
    if occupied is None:
        del data["grid"]["occupied_voxels"]
    else:
        data["grid"]["occupied_voxels"] = occupied
    return DatasetHeader.from_dict(data, "test header")


def test_training_sizes_the_tables_to_the_datasets_voxels():
    """Two occupied voxels of the header's 8^3 grid: the small test grid's 2**12 rows become
    2**10; a header without the count keeps the setting, and the model is built as its
    config says."""
    config = NetworkConfig(**SMALL)
    steps = dict(steps=2, batch_size=64, log_interval=2, device="cpu")
    sized = train(sphere_shards(), counted_header(2), TrainConfig(**steps), config)
    assert sized.network_config.log2_table_size == 10
    assert sized.network.encoder.grid.table.shape[0] == 2 * 2**10   # two hashed levels
    kept = train(sphere_shards(), counted_header(None), TrainConfig(**steps), config)
    assert kept.network_config.log2_table_size == 12
    assert kept.network.encoder.grid.table.shape[0] == 2 * 2**12


def test_training_steps_flush_denormals_and_leave_the_default_after(monkeypatch):
    """Inside the steps a product below float32's smallest normal is zero; after training,
    returned or raised, it is a denormal again."""
    if not torch.set_flush_denormal(False):
        pytest.skip("this CPU cannot flush denormals")

    def tiny():
        return float(torch.tensor(1e-30) * torch.tensor(1e-10))

    assert tiny() != 0
    seen = []
    original = training.TrainingStep.__call__

    def probed(self, batch, cancel=None):
        seen.append(tiny())
        if len(seen) == 5:
            raise VDNIFError("stopped")
        return original(self, batch, cancel)

    monkeypatch.setattr(training.TrainingStep, "__call__", probed)
    config = TrainConfig(steps=3, batch_size=64, log_interval=3, device="cpu")
    train(sphere_shards(), header(), config, NetworkConfig(**SMALL))
    assert seen == [0.0] * 3 and tiny() != 0
    with pytest.raises(VDNIFError, match="stopped"):
        train(sphere_shards(), header(), config, NetworkConfig(**SMALL))
    assert seen == [0.0] * 5 and tiny() != 0


def test_non_finite_loss_raises_naming_the_step(monkeypatch):
    calls = []

    def poisoned(*args, **kwargs):
        losses = task_losses(*args, **kwargs)
        calls.append(1)
        if len(calls) == 4:
            losses["distance"] = losses["distance"] * float("nan")
        return losses

    monkeypatch.setattr(training, "task_losses", poisoned)
    config = TrainConfig(steps=10, batch_size=32, log_interval=100, device="cpu", val_fraction=0.0)
    with pytest.raises(VDNIFError, match="step 4"):
        train(sphere_shards(), header(), config, NetworkConfig(**SMALL))


def test_bad_datasets_are_reported():
    config = TrainConfig(steps=1, batch_size=8, device="cpu")
    shards = sphere_shards()
    del shards[1]["normal"]
    with pytest.raises(VDNIFError, match="shard 1 lacks 'normal'"):
        train(shards, header(), config, NetworkConfig(**SMALL))
    shards = sphere_shards()
    shards[0]["p1"][3, 1] = np.nan
    with pytest.raises(VDNIFError, match="'p1' has non-finite"):
        train(shards, header(), config, NetworkConfig(**SMALL))
    shards = sphere_shards()
    shards[0]["material"][shards[0]["hit"] == 1] = 5
    with pytest.raises(VDNIFError, match="material"):
        train(shards, header(), config, NetworkConfig(**SMALL))
    with pytest.raises(VDNIFError, match="voxel size or extent is not a positive number"):
        header(voxel_size=0.0)
    with pytest.raises(VDNIFError, match="must be a training.header.DatasetHeader, got dict"):
        train(sphere_shards(), header_dict(), config, NetworkConfig(**SMALL))
    assert train(sphere_shards(), header(), config, NetworkConfig(**SMALL)).steps == 1
    with pytest.raises(VDNIFError, match="no training segments"):
        train([], header(), config, NetworkConfig(**SMALL))
    with pytest.raises(VDNIFError, match="batch_size"):
        TrainConfig(batch_size=0)


def test_variants():
    lsnif, deformed, proposed = (variant_config(name)
                                 for name in ("lsnif", "deformed", "proposed"))
    assert (lsnif.network.pe_bands, lsnif.network.distance_mode, lsnif.train.weighting) == (
        0,
        "fraction",
        "fixed",
    )
    assert deformed.network == lsnif.network and deformed.train == lsnif.train
    assert (lsnif.deformed_data, deformed.deformed_data, proposed.deformed_data) == (
        False,
        True,
        True,
    )
    assert (
        proposed.network.pe_bands,
        proposed.network.distance_mode,
        proposed.train.weighting,
    ) == (3, "log1p-fraction", "uncertainty")
    tuned = variant_config("proposed", pe_form="pi", steps=10)
    assert tuned.network.pe_form == "pi" and tuned.train.steps == 10
    with pytest.raises(VDNIFError, match="lsnif, deformed, proposed"):
        variant_config("nerf")
    with pytest.raises(VDNIFError, match="learning_rate"):
        variant_config("lsnif", learning_rate=1.0)


# --------------------------------------------------------------------------- two processes


def _ddp_worker(rank, port, folder):
    os.environ.update(
        RANK=str(rank),
        LOCAL_RANK=str(rank),
        WORLD_SIZE="2",
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
    )
    torch.set_num_threads(1)
    calls = []
    config = TrainConfig(steps=20, batch_size=64, log_interval=10, val_fraction=0.25, device="cpu")
    result = train(
        sphere_shards(n=512, shards=4, poses=8),
        header(),
        config,
        NetworkConfig(**SMALL),
        progress=calls.append,
    )
    torch.save(
        {
            "state": result.network.state_dict(),
            "calls": len(calls),
            "rank": result.rank,
            "steps": result.steps,
            "validation": result.validation,
        },
        os.path.join(folder, f"rank{rank}.pt"),
    )


def run_two_processes(worker, folder):
    """Runs ``worker(rank, port, folder)`` in two CPU processes of one gloo group on a free
    port and returns what each saved as ``folder/rank{r}.pt``."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    mp.spawn(worker, args=(port, str(folder)), nprocs=2, join=True)
    return [torch.load(folder / f"rank{r}.pt", weights_only=True) for r in (0, 1)]


@pytest.mark.slow
def test_two_cpu_processes_train_to_identical_weights(tmp_path):
    first, second = run_two_processes(_ddp_worker, tmp_path)
    assert (first["rank"], second["rank"]) == (0, 1) and first["steps"] == second["steps"] == 20
    assert (first["calls"], second["calls"]) == (2, 0)  # only the main process reports
    assert all(torch.equal(first["state"][key], second["state"][key]) for key in first["state"])
    assert first["validation"] == second["validation"] and first["validation"]["segments"] > 0


@pytest.mark.parametrize("cores", [1, 2])
def test_head_outputs_are_forward_chunk_by_chunk(monkeypatch, cores):
    """The held-out pass (the encoder of a chunk beside the MLP of the one before, on two
    cores; the fields after) gives ``forward``'s outputs of each chunk bit for bit, the
    fields read at the reference's hits and 0 elsewhere."""
    monkeypatch.setattr(threads, "cores", lambda: cores)
    torch.manual_seed(6)
    network = IntersectionNetwork(NetworkConfig(
        **SMALL, heads=Heads(albedo=True, material_count=2), normal_mode="hit",
        albedo_mode="hit")).eval()
    with torch.no_grad():
        for grid in network.modules():
            if isinstance(grid, HashGrid):
                grid.table.normal_()
    n, chunk = 1000, 96
    hit = torch.rand(n) < 0.3
    data = {"p0": torch.rand(n, 3), "p1": torch.rand(n, 3), "hit": hit,
            "hit_frac": torch.where(hit, torch.rand(n), 0.0)}
    outputs = head_outputs(network, data, chunk)
    with torch.no_grad():
        parts = [network(data["p0"][rows], data["p1"][rows], data["hit_frac"][rows],
                         data["hit"][rows].nonzero().squeeze(1))
                 for rows in (slice(start, start + chunk) for start in range(0, n, chunk))]
    assert set(outputs) == {"occlusion", "distance", "normal", "albedo", "material"}
    for key, value in outputs.items():
        assert torch.equal(value, torch.cat([part[key] for part in parts])), key
    assert torch.equal(outputs["normal"][~hit], torch.zeros(int((~hit).sum()), 3))


class _StandIn(torch.nn.Module):
    """Stands in for the network in ``head_outputs``: its features are p0, its MLPs run in
    float32, it has no point field, and ``heads`` answers."""

    def forward(self, p0, p1, hit_frac=None, hit=None):
        return self.heads(p0)

    def encoded(self, pairs):
        return (p0 for p0, _ in pairs)

    def add_fields(self, outputs, p0, p1, hit_frac, rows=None):
        pass

    def mlp_arithmetic(self, device):
        return contextlib.nullcontext()


class _Logit(_StandIn):
    """Occlusion logit 8 (x - 0.5) of p0's x."""

    def heads(self, features):
        return {"occlusion": 8.0 * (features[:, 0] - 0.5)}


def test_threshold_calibration_minimizes_the_larger_of_holes_and_extras_by_brute_force():
    """Rays of 1 to 12 segments in two poses whose ray numbers repeat; a third of the rays
    hit on their last segment. The network's logit (read from x) is noisy, about 1.5 on
    hit segments and -2 on the others. A ray is the reference's hit when one of its
    segments is, and the network's when one is above the threshold: the calibration finds
    the brute-force minimum of the larger of holes (hit rays the network misses) and extras
    (missed rays it hits) among its candidates, which is neither the fewest misclassified
    rays nor the fewest misclassified segments, and none without held-out rays."""
    generator = torch.Generator().manual_seed(3)
    lengths = torch.randint(1, 13, (3000,), generator=generator)
    ray_of_row = torch.repeat_interleave(torch.arange(len(lengths)), lengths)
    rows = len(ray_of_row)
    last = torch.ones(rows, dtype=torch.bool)
    last[:-1] = ray_of_row[1:] != ray_of_row[:-1]
    hit = last & (torch.rand(len(lengths), generator=generator) < 1 / 3)[ray_of_row]
    logit = torch.where(hit, 1.5, -2.0) + 1.5 * torch.randn(rows, generator=generator)
    x = torch.rand(rows, 3, generator=generator)
    x[:, 0] = 0.5 + logit / 8.0                         # _Logit answers 8 (x - 0.5)
    pose = (ray_of_row >= len(lengths) // 2).long()
    data = {"p0": x, "p1": x, "hit": hit, "hit_frac": torch.zeros(rows), "pose": pose,
            "ray": ray_of_row - pose * (len(lengths) // 2)}
    probability = torch.sigmoid(8.0 * (x[:, 0] - 0.5))
    candidates = (torch.arange(5, 46) / 50).tolist()
    rays = [torch.nonzero(ray_of_row == r).flatten() for r in range(len(lengths))]

    def holes_and_extras(threshold):
        answers = [(bool((probability[r] > threshold).any()), bool(hit[r].any()))
                   for r in rays]
        return (sum(truth and not said for said, truth in answers),
                sum(said and not truth for said, truth in answers))

    def by_segments(threshold):
        return int(((probability > threshold) != hit).sum())

    def best(errors):
        return min(candidates, key=lambda t: (errors(t), abs(t - 0.5)))

    threshold = calibrate_threshold(head_outputs(_Logit(), data), data)
    assert threshold == pytest.approx(best(lambda t: max(holes_and_extras(t))))
    assert threshold != pytest.approx(best(lambda t: sum(holes_and_extras(t))))
    assert threshold != pytest.approx(best(by_segments))
    empty = {key: value[:0] for key, value in data.items()}
    assert calibrate_threshold(head_outputs(_Logit(), empty), empty) is None


def test_threshold_calibration_by_segments_minimizes_held_out_errors_by_brute_force():
    """Each segment counted alone (a dataset without calibration views). Hits where x > 0.7
    (10 % of labels flipped): the best threshold is near sigmoid(8 * 0.2) = 0.83; the
    calibration finds the brute-force minimum among its candidates, and none without
    held-out data."""
    generator = torch.Generator().manual_seed(3)
    x = torch.rand(20000, 3, generator=generator)
    hit = (x[:, 0] > 0.7) ^ (torch.rand(20000, generator=generator) < 0.1)
    data = {"p0": x, "p1": x, "hit": hit, "hit_frac": torch.zeros(len(x))}
    probability = torch.sigmoid(8.0 * (x[:, 0] - 0.5))
    candidates = torch.arange(5, 46) / 50
    errors = [int(((probability > t) != hit).sum()) for t in candidates.tolist()]
    best = min(range(len(errors)), key=lambda i: (errors[i], abs(candidates[i] - 0.5)))
    threshold = calibrate_threshold(head_outputs(_Logit(), data), data, by_ray=False)
    assert threshold == pytest.approx(candidates[best].item())
    assert 0.78 <= threshold <= 0.88
    empty = {key: value[:0] for key, value in data.items()}
    assert calibrate_threshold(head_outputs(_Logit(), empty), empty, by_ray=False) is None


class _Table(_StandIn):
    """Each segment's occlusion logit and log-distance output read from p0's x (the row's
    index) in fixed tables; the distance table holds log1p(t/l)."""

    def __init__(self, logit, distance):
        super().__init__()
        self.logit, self.distance = logit, distance
        self.config = NetworkConfig(**SMALL, distance_mode="log1p-fraction")

    def heads(self, features):
        row = features[:, 0].long()
        return {"occlusion": self.logit[row], "distance": self.distance[row],
                "normal": torch.ones(len(row), 3)}


def test_candidate_calibration_places_hits_best_by_brute_force():
    """Random rays of 6 segments (two interleaved poses, rows in walk order) through a
    front surface and a back one two segments on, probabilities that are confident on the
    back, fall short on the front at random and stray before it: the candidate threshold
    is the brute-force best among those tried below the occlusion threshold (and that
    threshold itself), judged on the distance of each ray's first segment above it, over
    the rays that reference and network both hit."""
    generator = torch.Generator().manual_seed(5)
    rays, per_ray, h = 400, 6, 0.1
    n = rays * per_ray
    ray = torch.arange(rays).repeat_interleave(per_ray)
    slot = torch.arange(per_ray).repeat(rays)
    surface = torch.randint(0, per_ray + 2, (rays,), generator=generator)  # >= 6: no hit
    front, back = slot == surface[ray], slot == surface[ray] + 2   # the back: confident
    hit = front | back
    probability = torch.where(front, torch.rand(n, generator=generator),
                              0.3 * torch.rand(n, generator=generator) ** 4)
    probability = torch.where(back, torch.full((n,), 0.95), probability)
    logit = torch.log(probability / (1 - probability))
    fraction = torch.rand(n, generator=generator)
    seg_len = torch.full((n,), 1.0)
    rest_len = torch.full((n,), 1.0)
    predicted = torch.rand(n, generator=generator)
    data = {"p0": torch.stack([torch.arange(n, dtype=torch.float32)] * 3, 1),
            "hit": hit, "hit_frac": torch.where(hit, fraction, torch.zeros(n)),
            "rest_len": rest_len, "seg_len": seg_len, "t0": slot.float(),
            "pose": ray % 2, "ray": ray // 2}
    data["p1"] = data["p0"]
    network = _Table(logit, torch.log1p(predicted))
    distance = data["t0"].double() + predicted.double()     # the readout's fraction x 1.0

    def first(mask, value):
        out = torch.full((rays,), float("nan"), dtype=torch.float64)
        for r in range(rays):
            rows = torch.nonzero(mask & (ray == r)).flatten()
            if len(rows):
                out[r] = value[rows[0]]
        return out

    reference = first(hit, data["t0"].double() + data["hit_frac"].double())
    both = ~reference.isnan() & ~first(probability > 0.5, distance).isnan()
    tried = [t for t in CANDIDATE_THRESHOLDS if t < 0.5] + [0.5]
    errors = [(first(probability > t, distance) - reference)[both].abs().sum().item()
              for t in tried]
    best = min(range(len(tried)), key=lambda k: (errors[k], -k))
    assert errors[best] < errors[-1]          # the case is one where a lower threshold helps
    outputs = head_outputs(network, data)
    assert (calibrate_candidate_threshold(outputs, data, h, 0.5, "log1p-fraction")
            == pytest.approx(tried[best]))
    empty = {key: value[:0] for key, value in data.items()}
    assert calibrate_candidate_threshold(head_outputs(network, empty), empty, h, 0.5,
                                         "log1p-fraction") == 0.5


def test_a_dataset_with_calibration_views_calibrates_on_their_held_out_rays(monkeypatch):
    """Rows of rays numbered from the header's rays per pose on are calibration views
    (``view_rays``): training never draws them, and the occlusion threshold is the
    brute-force least of the larger of holes and extras (any segment above the threshold
    makes a ray a hit) over the held-out poses' view rays alone."""
    calls = []

    def spy(outputs, data, *args, **kwargs):
        calls.append(({key: value.clone() for key, value in data.items()}, kwargs))
        return calibrate(outputs, data, *args, **kwargs)

    calibrate = training.calibrate_threshold
    monkeypatch.setattr(training, "calibrate_threshold", spy)
    batches = training.Batches
    monkeypatch.setattr(training, "Batches", lambda data, size, seed: calls.append(
        ("trained", batches(data, size, seed))) or calls[-1][1])
    shards = sphere_shards(n=2048, poses=8, seed=1)     # training rays numbered below 2048
    per_pose = 4096
    for shard in shards:          # a third of the rows: rays of 3 segments, numbered after
        view = np.arange(len(shard["ray"])) % 3 == 0
        shard["ray"] = shard["ray"].copy()
        shard["ray"][view] = per_pose + np.arange(view.sum()) // 3
    viewed = DatasetHeader.from_dict({**header_dict(), "rays_per_pose": per_pose,
                                      "view_rays": 700}, "test header")
    settings = variant_config("proposed", **SMALL, steps=50, batch_size=128,
                              val_fraction=0.25, lr_mlp=1e-2, device="cpu")
    result = train(shards, viewed, settings.train, settings.network)
    trained = next(value for name, value in calls if name == "trained").data
    views = [(data, kwargs) for data, kwargs in calls if isinstance(data, dict)]
    assert len(views) == 1 and views[0][1] == {}        # by ray, no fallback to segments
    data = views[0][0]
    assert (data["ray"] >= per_pose).all() and len(data["ray"]) > 100
    assert set(data["pose"].tolist()) <= set(result.val_poses)
    rows = sum(int(((s["ray"] >= per_pose) & np.isin(s["pose"], result.val_poses)).sum())
               for s in shards)
    assert len(data["ray"]) == rows
    untrained = sum(int(((s["ray"] >= per_pose) | np.isin(s["pose"], result.val_poses)).sum())
                    for s in shards)
    assert len(trained["p0"]) == 2048 - untrained and untrained < 2048 * 0.6

    with torch.no_grad():
        probability = torch.sigmoid(result.network(data["p0"], data["p1"])["occlusion"])
    rays = {}
    for row, key in enumerate(zip(data["pose"].tolist(), data["ray"].tolist())):
        rays.setdefault(key, []).append(row)
    tried = [k / 50 for k in range(5, 46)]
    answers = [[(bool((probability[r] > t).any()), bool(data["hit"][r].any()))
                for r in rays.values()] for t in tried]
    errors = [max(sum(truth and not said for said, truth in told),
                  sum(said and not truth for said, truth in told)) for told in answers]
    best = min(range(len(tried)), key=lambda k: (errors[k], abs(tried[k] - 0.5)))
    assert result.thresholds.occlusion == pytest.approx(tried[best])


@pytest.mark.parametrize("variant, poses", [("lsnif", 1), ("deformed", 8), ("proposed", 8)])
def test_every_variant_calibrates_its_thresholds_on_held_out_data(monkeypatch, variant, poses):
    """lsnif's dataset has one pose: it holds out rays of it, the others hold out poses. Each
    variant's thresholds are the brute-force best on held-out segments that training never
    drew from, and the occlusion threshold beats the uncalibrated 0.5 there."""
    seen = {}

    def spy(name, function):
        def wrapped(network, data, *args, **kwargs):
            seen[name] = {key: value.clone() for key, value in data.items()}
            return function(network, data, *args, **kwargs)
        monkeypatch.setattr(training, name, wrapped)

    spy("calibrate_threshold", training.calibrate_threshold)
    spy("calibrate_candidate_threshold", training.calibrate_candidate_threshold)
    batches = training.Batches
    monkeypatch.setattr(training, "Batches", lambda data, size, seed: seen.setdefault(
        "trained", batches(data, size, seed)))
    shards = sphere_shards(n=2048, poses=poses, seed=1)
    # lsnif on one pose of this small sphere stays near the all-miss answer; with the normal
    # head, whose target is a function of the position, its grid learns enough of the sphere
    # that some held-out rays are hit by both it and the reference (the candidate check
    # below needs them). The normal field answers the normal without teaching the MLP.
    fields = {"normal_mode": "segment"} if variant == "lsnif" else {}
    settings = variant_config(variant, **SMALL, **fields, steps=200, batch_size=128,
                              val_fraction=0.25, lr_mlp=1e-2, device="cpu")
    result = train(shards, header(), settings.train, settings.network)
    held_out, trained = seen["calibrate_threshold"], seen["trained"].data
    assert seen["calibrate_candidate_threshold"]["p0"].equal(held_out["p0"])
    # held out: about a quarter of the segments, none of them a training segment
    assert 0.15 < len(held_out["p0"]) / 2048 < 0.35
    assert len(held_out["p0"]) + len(trained["p0"]) == 2048
    rows = {tuple(row) for row in trained["p0"].tolist()}
    assert not any(tuple(row) in rows for row in held_out["p0"].tolist())
    assert (len(result.val_poses) == 0) == (poses == 1)

    with torch.no_grad():
        outputs = result.network(held_out["p0"], held_out["p1"])
    probability = torch.sigmoid(outputs["occlusion"]).double()
    hit = held_out["hit"]
    tried = [k / 50 for k in range(5, 46)]
    errors = [int(((probability >= t) != hit).sum()) for t in tried]
    best = min(range(len(tried)), key=lambda k: (errors[k], abs(tried[k] - 0.5)))
    assert result.thresholds.occlusion == pytest.approx(tried[best])
    assert errors[best] < errors[tried.index(0.5)]        # calibration mattered here

    # candidate: one segment per ray, so each ray's first segment above t is that segment
    occlusion = result.thresholds.occlusion
    fraction = readout(outputs, settings.network.distance_mode, 0.125,
                       held_out["rest_len"])["fraction"].double()
    placed = held_out["t0"].double() + fraction * held_out["seg_len"].double()
    reference = held_out["t0"].double() + held_out["hit_frac"].double() * held_out[
        "seg_len"].double()
    both = hit & (probability > occlusion)
    candidates = [t for t in CANDIDATE_THRESHOLDS if t < occlusion] + [occlusion]
    # a ray both hit is placed by every lower threshold on the same segment: equal errors,
    # so the brute-force choice is the highest, the occlusion threshold itself, unless no
    # ray is hit by both
    error = [(placed - reference)[both & (probability > t)].abs().sum().item()
             for t in candidates]
    assert both.any()
    chosen = max(k for k in range(len(candidates)) if error[k] == min(error))
    assert result.thresholds.candidate == pytest.approx(candidates[chosen])

    # The final validation reads the calibrations' pass over the held-out rows: the same
    # figures as a fresh evaluation with the calibrated thresholds.
    assert result.validation == evaluate(result.network, held_out, 0.125)


def test_device_names():
    from vdnif_addon.training.distributed import resolve_device

    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(VDNIFError, match="unknown device 'gpu': expected one of auto, cpu, cuda"):
        resolve_device("gpu")
    # A device resolved by one layer passes through the next unchanged.
    assert resolve_device(resolve_device("cpu")) == torch.device("cpu")
    with pytest.raises(VDNIFError, match="unknown device 'meta'"):
        resolve_device(torch.device("meta"))


def test_auto_and_cuda_need_a_gpu_that_both_torch_and_warp_see(monkeypatch, capsys):
    """torch can see a GPU that Warp's CUDA 13 wheels cannot use (an old driver or GPU):
    "auto" then stays on the CPU and says why, once; "cuda" is refused on one line. Where
    both see it, both pick it. (torch's and Warp's device queries are faked.)"""
    from vdnif_addon.kernels import runtime
    from vdnif_addon.training import distributed

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    monkeypatch.delenv("LOCAL_RANK", raising=False)
    monkeypatch.setattr(distributed, "_warned", set())
    monkeypatch.setattr(runtime, "cuda_device_count", lambda: 0)
    assert distributed.resolve_device("auto") == torch.device("cpu")
    assert distributed.resolve_device("auto") == torch.device("cpu")
    said = capsys.readouterr().err.splitlines()
    assert len(said) == 1 and "torch sees a CUDA GPU and Warp" in said[0]
    assert said[0].endswith("using the CPU")
    with pytest.raises(VDNIFError, match="setting device is 'cuda' but torch sees a CUDA GPU "
                                         "and Warp .* NVIDIA driver for CUDA 13"):
        distributed.resolve_device("cuda")
    monkeypatch.setattr(runtime, "cuda_device_count", lambda: 1)
    assert distributed.resolve_device("auto") == torch.device("cuda", 0)
    assert distributed.resolve_device("cuda") == torch.device("cuda", 0)



def test_each_rank_trains_on_its_own_gpu(monkeypatch):
    """LOCAL_RANK picks the GPU among the visible ones, or the only one a scheduler leaves
    each task; and the group sets it as the current device before NCCL's first collective
    (which otherwise puts every rank's tensors on cuda:0). CUDA is faked."""
    from vdnif_addon.kernels import runtime
    from vdnif_addon.training import distributed

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(runtime, "cuda_device_count", lambda: 4)
    for visible, rank, expected in ((4, "2", 2), (1, "3", 0), (4, "0", 0)):
        monkeypatch.setattr(torch.cuda, "device_count", lambda visible=visible: visible)
        monkeypatch.setenv("LOCAL_RANK", rank)
        assert distributed.resolve_device("cuda") == torch.device("cuda", expected)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setenv("LOCAL_RANK", "3")
    with pytest.raises(VDNIFError, match="LOCAL_RANK 3 names no visible GPU \\(2 visible\\)"):
        distributed.resolve_device("cuda")
    chosen = []
    monkeypatch.setattr(torch.cuda, "set_device", chosen.append)
    monkeypatch.setattr(distributed.dist, "is_initialized", lambda: True)
    monkeypatch.setattr(distributed.dist, "get_rank", lambda: 1)
    monkeypatch.setattr(distributed.dist, "get_world_size", lambda: 2)
    monkeypatch.setenv("WORLD_SIZE", "2")
    group = distributed.ProcessGroup.from_environment(torch.device("cuda", 1))
    assert chosen == [torch.device("cuda", 1)] and (group.rank, group.world) == (1, 2)
    assert distributed.ProcessGroup.from_environment(torch.device("cpu")).rank == 1
    assert chosen == [torch.device("cuda", 1)]
