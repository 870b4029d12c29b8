"""CUDA streams, checked on the CPU with stand-ins for torch's and Warp's stream calls: the
encoder launches on one Warp stream per torch stream, made once; the render runs on the
device's default stream (the one Warp's host reads copy on) after the caller's stream and
before its later work."""

import contextlib
import types

import torch
import warp as wp

from vdnif_addon.inference import neural_render as render
from vdnif_addon.kernels import encoder, launches, runtime


class FakeStream:
    """A torch CUDA stream as the code reads one: its device, handle and waits."""

    def __init__(self, handle, log):
        self.device, self.cuda_stream, self.log = torch.device("cuda", 0), handle, log

    def wait_stream(self, other):
        self.log.append(("wait", self.cuda_stream, other.cuda_stream))


def fake_streams(monkeypatch, log):
    """torch.cuda's current/default stream and Warp's stream_from_torch faked; returns the
    {"current": stream} switch and the list of Warp streams made."""
    streams = {"current": FakeStream(7, log), "default": FakeStream(0, log)}
    made = []

    def from_torch(stream):
        made.append(types.SimpleNamespace(handle=stream.cuda_stream))
        return made[-1]

    monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: streams["current"])
    monkeypatch.setattr(torch.cuda, "default_stream", lambda device=None: streams["default"])
    monkeypatch.setattr(wp, "stream_from_torch", from_torch)
    monkeypatch.setattr(launches, "_STREAMS", {})
    return streams, made


def test_the_encoder_reuses_one_warp_stream_per_torch_stream(monkeypatch):
    """A Warp stream made per launch would register the torch stream with Warp and
    unregister it when collected, again and again, while it is in use."""
    streams, made = fake_streams(monkeypatch, [])
    monkeypatch.setattr(runtime, "load", lambda module, device: None)
    points = types.SimpleNamespace(device=torch.device("cuda", 0))
    targets = [encoder._target(points) for _ in range(3)]
    assert targets == [("cuda:0", made[0])] * 3 and len(made) == 1
    streams["current"] = side = FakeStream(9, [])      # under torch.cuda.stream(side)
    assert encoder._target(points) == ("cuda:0", made[1]) and made[1].handle == 9
    streams["current"] = FakeStream(7, [])              # the first stream again
    assert encoder._target(points)[1] is made[0] and len(made) == 2
    assert side.cuda_stream == 9
    cpu = types.SimpleNamespace(device=torch.device("cpu"))
    assert encoder._target(cpu) == ("cpu", None)


def test_the_render_runs_on_the_default_stream_between_the_callers_work(monkeypatch):
    """Warp's host reads (``array.numpy()``) copy on the default stream: under a side
    ``torch.cuda.stream`` a render on the side stream would be read before it is done."""
    log = []
    streams, made = fake_streams(monkeypatch, log)

    @contextlib.contextmanager
    def torch_stream(stream):
        log.append(("torch stream", stream.cuda_stream))
        yield

    @contextlib.contextmanager
    def warp_scope(stream):
        log.append(("warp stream", stream.handle))
        yield

    monkeypatch.setattr(torch.cuda, "stream", torch_stream)
    monkeypatch.setattr(wp, "ScopedStream", warp_scope)
    with render._device_stream("cuda:0"):
        log.append("render")
    assert log == [("wait", 0, 7), ("torch stream", 0), ("warp stream", 0), "render",
                   ("wait", 7, 0)]
    log.clear()
    with render._device_stream("cpu"):
        log.append("render")
    assert log == ["render"] and len(made) == 1
