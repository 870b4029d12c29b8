"""The optimizer step's non-finite and cancel checks read the device only at check points
(every ``log_interval`` steps, the last step, a cancel): between them the non-finite flag
stays on the device and the fused Adam skips every update from the first bad step on.
The oracle is the step as it was, reading both flags on the host after every backward pass.
"""

import math
import os
import threading

import pytest
import torch
from host_reads import counting_host_reads
from oracles import training_step as oracle
from test_train import SMALL, header, run_two_processes, sphere_shards
from torch.nn.parallel import DistributedDataParallel

from vdnif_addon.errors import VDNIFError
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import NetworkConfig, TrainConfig
from vdnif_addon.training import train as training
from vdnif_addon.training.data import Batches, load_segments
from vdnif_addon.training.distributed import ProcessGroup
from vdnif_addon.training.losses import make_weighting


def steps_of(kind, steps=25, log_interval=10, seed=3, weighting="uncertainty"):
    """A training step of ``kind`` (the product's or the oracle's) on the sphere, the batches
    it draws and its network, all from fixed seeds."""
    config = TrainConfig(steps=steps, batch_size=64, log_interval=log_interval, device="cpu",
                         weighting=weighting)
    network_config = NetworkConfig(**SMALL, heads=header().heads.network_heads())
    torch.manual_seed(seed)
    network = IntersectionNetwork(network_config)
    weighting = make_weighting(config.weighting, list(network.head_sizes),
                               config.weighting_start)
    objective = training.Objective(network, weighting, 0.125)
    data = load_segments(sphere_shards(), network_config.heads)
    return kind(objective, config), Batches(data, config.batch_size, seed), objective


def weights(module):
    return {key: value.clone() for key, value in module.state_dict().items()}


def same(first, second):
    return first.keys() == second.keys() and all(
        torch.equal(first[key], second[key]) for key in first)


def test_finite_steps_give_the_weights_of_the_per_step_check():
    """Bit for bit: the deferred check changes nothing while every step is finite."""
    results = []
    for kind in (training.TrainingStep, oracle.TrainingStep):
        step, batches, objective = steps_of(kind)
        totals = [step(batches.next())[1].item() for _ in range(25)]
        results.append((weights(objective), totals,
                        [g["lr"] for g in step.optimizer.param_groups]))
    (new, new_totals, new_lr), (old, old_totals, old_lr) = results
    assert same(new, old) and new_totals == old_totals and new_lr == old_lr


@pytest.mark.parametrize("steps, log_interval", [(25, 10), (30, 10), (7, 100)])
def test_the_device_is_read_only_at_check_points(steps, log_interval):
    """At most one host read per ``log_interval`` steps, plus the last step's."""
    step, batches, _ = steps_of(training.TrainingStep, steps, log_interval)
    batch_list = [batches.next() for _ in range(steps)]
    with counting_host_reads() as reads:
        for batch in batch_list:
            step(batch)
    assert len(reads) <= math.ceil(steps / log_interval) + 1, reads


def poison_loss_at(monkeypatch, bad_step):
    """The distance loss of the ``bad_step``-th forward pass (1-based) becomes NaN."""
    calls = []

    def poisoned(*args, **kwargs):
        losses = training_losses(*args, **kwargs)
        calls.append(1)
        if len(calls) == bad_step:
            losses["distance"] = losses["distance"] * float("nan")
        return losses

    training_losses = training.task_losses
    monkeypatch.setattr(training, "task_losses", poisoned)


def poison_gradient_at(objective, bad_step):
    """The ``bad_step``-th backward pass (1-based) gives the output layer an infinite
    gradient while the loss stays finite."""
    calls = []

    def hook(grad):
        calls.append(1)
        return grad * math.inf if len(calls) == bad_step else grad

    objective.network.mlp[-1].weight.register_hook(hook)


def after_steps(count):
    """The weights after ``count`` finite steps of the oracle."""
    step, batches, objective = steps_of(oracle.TrainingStep)
    for _ in range(count):
        step(batches.next())
    return weights(objective)


@pytest.mark.parametrize("where", ["loss", "gradient"])
@pytest.mark.parametrize("bad_step", [1, 4, 10])
def test_a_non_finite_step_raises_naming_it_and_no_update_is_applied_from_it(
        monkeypatch, where, bad_step):
    """Steps 1..9 are no check point at log_interval 10: the error comes at step 10 and
    names the first bad step; the weights and Adam's step counts are those before it."""
    step, batches, objective = steps_of(training.TrainingStep)
    if where == "loss":
        poison_loss_at(monkeypatch, bad_step)
    else:
        poison_gradient_at(objective, bad_step)
    taken = 0
    with pytest.raises(VDNIFError, match=f"stopped at step {bad_step}: the loss or its gradient"
                       " is not finite") as error:
        for _ in range(25):
            step(batches.next())
            taken += 1
    assert taken == 9  # raised at the check point of step 10
    if where == "loss":
        assert "distance=nan" in str(error.value)
    monkeypatch.undo()
    assert same(weights(objective), after_steps(bad_step - 1))
    counts = {float(state["step"]) for state in step.optimizer.state.values()}
    assert counts <= {float(bad_step - 1)}


def test_cancel_stops_before_the_next_update_between_check_points():
    cancel = threading.Event()
    step, batches, objective = steps_of(training.TrainingStep)
    for _ in range(3):
        assert step(batches.next(), cancel)[0] is False
    cancel.set()
    with counting_host_reads() as reads:
        assert step(batches.next(), cancel)[0] is True
    assert len(reads) <= 1
    assert same(weights(objective), after_steps(3))


def test_a_bad_step_before_a_cancel_is_reported(monkeypatch):
    cancel = threading.Event()
    step, batches, objective = steps_of(training.TrainingStep)
    poison_loss_at(monkeypatch, 2)
    with pytest.raises(VDNIFError, match="stopped at step 2"):
        for _ in range(3):
            step(batches.next(), cancel)
        cancel.set()
        step(batches.next(), cancel)
    monkeypatch.undo()
    assert same(weights(objective), after_steps(1))


# --------------------------------------------------------------------------- two processes


def _group_worker(rank, port, folder):
    """Rank 1 alone sees a NaN loss at step 4 whose gradients stay finite (a constant term
    under the fixed weighting), then, in a second run, alone sets cancel at step 3."""
    os.environ.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE="2",
                      MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    torch.set_num_threads(1)
    group = ProcessGroup.from_environment(torch.device("cpu"))
    calls = []

    def poisoned(*args, **kwargs):
        losses = training_losses(*args, **kwargs)
        calls.append(1)
        if rank == 1 and len(calls) == 4:
            losses["distance"] = losses["distance"] + float("nan")
        return losses

    def grouped(objective, config):
        return training.TrainingStep(objective, config, DistributedDataParallel(objective),
                                     group)

    training_losses = training.task_losses
    training.task_losses = poisoned
    step, batches, objective = steps_of(grouped, weighting="fixed")
    result = {"calls": 0}
    try:
        for _ in range(25):
            step(batches.next())
            result["calls"] += 1
    except VDNIFError as error:
        result["error"] = str(error)
    result["diverged"] = weights(objective)
    training.task_losses = training_losses

    cancel = threading.Event()
    step, batches, objective = steps_of(grouped, weighting="fixed")
    for call in range(1, 26):
        if rank == 1 and call == 3:
            cancel.set()
        if step(batches.next(), cancel)[0]:
            break
    result["cancelled_at"] = call
    result["cancelled"] = weights(objective)
    torch.save(result, os.path.join(folder, f"rank{rank}.pt"))
    group.close()


@pytest.mark.slow
def test_the_processes_of_a_group_skip_and_stop_alike(tmp_path):
    first, second = run_two_processes(_group_worker, tmp_path)
    for result in (first, second):
        assert result["calls"] == 9 and "stopped at step 4" in result["error"]
        assert result["cancelled_at"] == 10  # the first check point after the cancel
    assert same(first["diverged"], second["diverged"])
    assert same(first["cancelled"], second["cancelled"])
