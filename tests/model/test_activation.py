"""The MLPs' ReLU by bfloat16 bits against torch's ReLU: values, NaNs, -0, gradients, and
a network's predictions and training steps with either."""

import pytest
import torch
from test_train import bfloat16_steps, random_batch

from vdnif_addon.model.activation import ReLU
from vdnif_addon.model.network import IntersectionNetwork
from vdnif_addon.settings import Heads, NetworkConfig

SPECIAL = [0.0, -0.0, float("inf"), -float("inf"), float("nan"), 1e-40, -1e-40, 3.0, -3.0,
           3e38, -3e38, 2.0**-133, -(2.0**-133)]


def values(dtype):
    """Special values, both NaN signs, every bfloat16 bit pattern (as ``dtype``) and random
    normals."""
    every = torch.arange(-(2**15), 2**15, dtype=torch.int32).to(torch.int16)
    patterns = every.view(torch.bfloat16).to(dtype)
    negative_nan = torch.tensor([-1], dtype=torch.int16).view(torch.bfloat16).to(dtype)
    generator = torch.Generator().manual_seed(0)
    return torch.cat([torch.tensor(SPECIAL, dtype=dtype), negative_nan, patterns,
                      torch.randn(50_000, generator=generator).to(dtype)])


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float32])
def test_relu_equals_torch_bit_for_bit_but_for_minus_zero(dtype):
    """Every bfloat16 bit pattern: torch's ReLU's bits, but -0 made +0; NaNs stay NaN
    whatever their sign (their payload kept, where torch writes its own), -inf is 0; in
    place. float32 is torch's own ReLU."""
    x = values(dtype)
    expected = torch.relu(x)
    got = x.clone()
    out = ReLU()(got)
    assert out.data_ptr() == got.data_ptr()                 # in place
    bits = torch.int16 if dtype == torch.bfloat16 else torch.int32
    assert torch.equal(out.isnan(), x.isnan()) and torch.equal(expected.isnan(), x.isnan())
    differ = (out.view(bits) != expected.view(bits)) & ~x.isnan()
    if dtype == torch.bfloat16:
        minus_zero = (x == 0) & torch.signbit(x)
        assert torch.equal(differ, minus_zero) and minus_zero.any()
        assert (out[minus_zero].view(bits) == 0).all()      # +0
    else:
        assert not differ.any()


def test_relu_gradient_is_torchs():
    """Through autograd, as a layer's in-place activation: the same output and input
    gradient as torch's in-place ReLU."""
    generator = torch.Generator().manual_seed(1)
    weights = torch.randn(64, 32, generator=generator, requires_grad=True)
    inputs = torch.randn(500, 64, generator=generator)
    upstream = torch.randn(500, 32, generator=generator).to(torch.bfloat16)
    results = []
    for relu in (ReLU(), torch.nn.ReLU(inplace=True)):
        weights.grad = None
        out = relu((inputs @ weights).to(torch.bfloat16))
        out.backward(upstream)
        results.append((out.detach(), weights.grad.clone()))
    (ours, our_grad), (theirs, their_grad) = results
    assert torch.equal(ours, theirs) and torch.equal(our_grad, their_grad)


def torch_relu(network):
    """``network`` with torch's in-place ReLU in place of ``ReLU``."""
    for module in network.modules():
        if isinstance(module, torch.nn.Sequential):
            for index, layer in enumerate(module):
                if isinstance(layer, ReLU):
                    module[index] = torch.nn.ReLU(inplace=True)
    return network


def test_bfloat16_predictions_and_steps_equal_those_with_torchs_relu():
    """A network's bfloat16 predictions, and its weights after bfloat16 training steps, are
    those of the same network with torch's ReLU, bit for bit."""
    config = NetworkConfig(levels=2, base_resolution=16, log2_table_size=12, width=32,
                           depth=2, normal_mode="hit", albedo_mode="hit",
                           heads=Heads(albedo=True, material_count=2))
    torch.manual_seed(2)
    batch = random_batch(3000, 0.4, materials=2)
    outcomes = []
    for swap in (False, True):
        torch.manual_seed(3)
        network = IntersectionNetwork(config)
        if swap:
            torch_relu(network)
        bfloat16_steps(network, batch, 3).eval()
        network.precision = "bfloat16"
        predicted = network.predict(batch["p0"], batch["p1"], batch["rest_len"], 0.5)
        outcomes.append(({name: p.detach().clone() for name, p in network.named_parameters()},
                         predicted))
    (weights, predicted), (expected_weights, expected) = outcomes
    assert sum(isinstance(m, ReLU) for m in IntersectionNetwork(config).modules()) == 5
    for name, value in expected_weights.items():
        assert torch.equal(weights[name], value), name
    for key, value in expected.items():
        assert torch.equal(predicted[key], value), key
