"""The first run on a machine compiles the kernels for tens of seconds: the jobs' progress line
(the panel's and the status bar's) says so with its time instead of "starting", and says
nothing of it when the kernels load from the cache."""

import os
import pathlib
import re
import subprocess
import sys
import threading
import time

import pytest

from vdnif_addon import worker
from vdnif_addon.kernels import runtime
from vdnif_addon.training.job import JobState
from vdnif_addon.worker import KernelCompile, WorkerJob

REPO = pathlib.Path(__file__).resolve().parents[2]

COMPILING = r"compiling kernels \(first run on this machine\) (\d+) s"


def loading_job(name):
    """A job whose work loads the kernels of the Warp module ``name`` for the CPU."""

    def work(_source, progress, _deliver):
        runtime.load(name, "cpu")
        progress(1, 1)
        return "loaded", None

    return WorkerJob("dataset", 4, "poses", work)


def lines_until(job, done, timeout=60):
    """The job's progress lines, polled as the UI's timer does, until ``done(line)``."""
    seen, end = [], time.monotonic() + timeout
    while time.monotonic() < end:
        seen.append(job.poll().line())
        if done(seen[-1]):
            return seen
        time.sleep(0.02)
    raise AssertionError(f"never seen: {seen[-3:]}")


def test_a_job_shows_a_kernel_compile_with_its_time(monkeypatch):
    """A load that takes long (Warp compiling; here a stand-in that waits) replaces
    "starting" with the compile and its seconds, counting up, until the load is done."""
    release = threading.Event()
    monkeypatch.setattr(runtime, "_loaded", set())
    monkeypatch.setattr(runtime.wp, "load_module",
                        lambda name, device: release.wait(timeout=60))
    # the first poll after the start must come before the compile counts as long: 3 s, not
    # the product's half second, so that a test worker descheduled on a loaded machine
    # still polls in time
    monkeypatch.setattr(worker, "COMPILE_SHOWN_AFTER_S", 3.0)
    job = loading_job("vdnif.kernels.walk")
    assert job.poll().line() == "dataset: 0/4 poses, starting"
    job.start()
    try:
        lines = lines_until(job, lambda line: re.search(COMPILING, line) and int(
            re.search(COMPILING, line).group(1)) >= 1)
    finally:
        release.set()
    state = job.join(timeout=30)
    compiling = [line for line in lines if "compiling" in line]
    assert re.fullmatch(f"dataset: 0/4 poses, {COMPILING}", compiling[-1])
    assert lines[0] == "dataset: 0/4 poses, starting", "not before the compile was long"
    assert state.status == "completed" and state.line() == "loaded"
    assert worker.compile_line() is None


def test_a_cached_load_shows_no_compile(monkeypatch):
    monkeypatch.setattr(runtime, "_loaded", set())
    monkeypatch.setattr(runtime.wp, "load_module", lambda name, device: None)
    job = loading_job("vdnif.kernels.walk")
    job.start()
    assert job.join(timeout=30).status == "completed"
    assert worker.compile_line() is None and job.state.line() == "loaded"


def test_training_shows_the_compile_and_loads_in_a_row_are_one_phase(monkeypatch):
    """Training's line too; the modules compiled one after another count as one compile,
    its time from the first one's start; a load a while later starts a new one."""
    monkeypatch.setattr(worker, "COMPILE_SHOWN_AFTER_S", 0.0)

    def seconds():
        line = JobState(200).line()
        assert re.fullmatch(f"step 0/200, {COMPILING}", line), line
        return int(re.fullmatch(f"step 0/200, {COMPILING}", line).group(1))

    with KernelCompile():
        time.sleep(1.0)
    with KernelCompile():
        assert seconds() >= 1, "the second module's compile continues the first one's"
    assert JobState(200).line() == "step 0/200, starting"
    time.sleep(1.2)
    with KernelCompile():
        assert seconds() == 0, "a compile long after the last is a new one"


@pytest.mark.slow
def test_a_real_first_compile_is_shown(tmp_path):
    """In a fresh process with an empty kernel cache: the cast kernels compile (seconds),
    and the job's line says so while they do."""
    script = f"""
import re, sys, time
sys.path.insert(0, {str(REPO)!r})
sys.path.insert(0, {os.path.dirname(__file__)!r})
from test_kernel_compile_progress import COMPILING, lines_until, loading_job
from vdnif_addon.kernels import cast
job = loading_job(cast.WARP_MODULE)
start = time.monotonic()
job.start()
lines = lines_until(job, lambda line: line == "loaded", timeout=300)
print("took", round(time.monotonic() - start, 1), "s")
print("\\n".join(line for line in lines if re.search(COMPILING, line))[-200:])
"""
    env = dict(os.environ, VDNIF_KERNEL_CACHE=str(tmp_path / "kernels"))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert re.search(f"dataset: 0/4 poses, {COMPILING}", done.stdout), done.stdout
    assert "compiled the 'cast' kernels for cpu" in done.stderr
