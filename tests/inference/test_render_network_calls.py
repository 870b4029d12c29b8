"""A render's network calls: a wave goes to the network in one batch where the device's
``PREDICT_BATCH`` holds it (on CUDA a batch costs a dozen launches whatever its size).
Checked on the CPU by giving the CPU CUDA's batch: the render passes no batch of its own,
so the device's is what splits a wave."""

import pytest
from test_render import bent_ball
from test_render_host_reads import small_network, view

from vdnif_addon.inference import neural_render as render
from vdnif_addon.kernels.cells import DeviceCells
from vdnif_addon.model import network as network_module


@pytest.mark.parametrize("device_batch", [network_module.PREDICT_BATCH["cuda"], 64])
def test_a_wave_is_one_network_call_where_the_devices_batch_holds_it(monkeypatch,
                                                                      device_batch):
    """The encoder of the segments runs once per wave with CUDA's batch, though the first
    wave holds more segments than the CPU's own batch; with a batch of 64 the waves take
    more calls, so the count can fail."""
    ball = mesh, grid, bend = bent_ball(12)
    cells = DeviceCells(grid, corners=bend)
    network = small_network()
    origins, directions = view(320, ball)      # a first wave of more than 2^14
    monkeypatch.setitem(network_module.PREDICT_BATCH, "cpu", device_batch)
    calls, segments = [], []
    hook = network.encoder.register_forward_hook(
        lambda module, inputs, output: calls.append(len(output)))
    original = network.predict

    def predict(p0, *args, **kwargs):
        segments.append(len(p0))
        return original(p0, *args, **kwargs)

    monkeypatch.setattr(network, "predict", predict)
    _, stats = render.neural_passes(network, grid, mesh.albedo_table(), cells, origins,
                                    directions, schedule=(1,), lanes=1, wave_floor=0)
    hook.remove()
    assert len(segments) == stats["waves"] >= 4
    assert sum(calls) == sum(segments)
    expected = sum(-(-count // device_batch) for count in segments)
    assert len(calls) == expected
    assert max(segments) > 1 << 14        # more than the CPU's own batch
    if device_batch == 64:
        assert len(calls) > stats["waves"]
    else:
        assert len(calls) == stats["waves"]
