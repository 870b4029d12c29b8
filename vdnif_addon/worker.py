"""Long work for the UI: a worker thread with progress, ETA and cancel, fed by Blender's main
thread, so that Blender stays responsive while it runs.

Blender's data (objects, meshes, the depsgraph, images) may only be read or written on its
main thread: Blender changes it between Python calls there (redraws, undo, the timeline) and
its API takes no lock, so a worker thread that read it could see half-updated data or freed
memory. A ``WorkerJob`` therefore splits its work in two: ``reads``, a generator run a bit at
a time by ``tick`` on the main thread, reads what the work needs from Blender into plain
arrays and puts them into a ``Feed``; the ``work`` function runs in the worker thread on
those arrays alone. Results that must go back into Blender (images) come out through
``deliver`` and are handled by ``tick`` on the main thread too.

In background mode (batch runs, scripts) ``run`` does the same work in the calling thread,
reading Blender directly. This module imports neither bpy nor torch.

``WorkerJob`` is the one job of the extension: the panel's long buttons and the batch
commands run their work through it (``blender.ui_jobs`` makes the jobs that read poses,
``training.job.TrainingJob`` is the one whose work reads no Blender data).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from typing import Any

from .errors import VDNIFError


class JobCancelled(Exception):
    """Raised inside a job's work once its cancel was asked (at the next progress call or
    read from the feed)."""


def duration(seconds: float | None) -> str:
    """``12 s`` or ``m:ss``; ``?`` when unknown."""
    if seconds is None:
        return "?"
    seconds = round(seconds)
    return f"{seconds // 60}:{seconds % 60:02d}" if seconds >= 60 else f"{seconds} s"


COMPILE_SHOWN_AFTER_S = 0.5
"""A kernel load that takes longer than this is a compile (loading a cached one takes a few
milliseconds): the jobs' progress line says so from then on."""
_compile = {"start": None, "running": 0, "ended": None}
_compile_lock = threading.Lock()


class KernelCompile:
    """Marks a kernel load (``kernels.runtime.load``) in any thread, for ``compile_line``.
    Loads that follow each other within a second make one compile phase."""

    def __enter__(self) -> KernelCompile:
        with _compile_lock:
            now = time.monotonic()
            ended = _compile["ended"]
            if not _compile["running"] and (ended is None or now - ended > 1.0):
                _compile["start"] = now
            _compile["running"] += 1
        return self

    def __exit__(self, *_: object) -> None:
        with _compile_lock:
            _compile["running"] -= 1
            _compile["ended"] = time.monotonic()


def compile_line() -> str | None:
    """'compiling kernels (first run on this machine) 12 s' while kernels have been loading
    for longer than ``COMPILE_SHOWN_AFTER_S``, else None."""
    with _compile_lock:
        if not _compile["running"]:
            return None
        seconds = time.monotonic() - _compile["start"]
    if seconds < COMPILE_SHOWN_AFTER_S:
        return None
    return f"compiling kernels (first run on this machine) {duration(seconds)}"


class Progress:
    """What every job's state shares (a dataclass with ``status``, ``cancelling`` and
    ``message`` fields, and ``done_of()``: (done, total) in its own unit)."""

    @property
    def done(self) -> bool:
        return self.status != "running"

    @property
    def fraction(self) -> float:
        count, total = self.done_of()
        return count / total if total else 0.0

    def _line(self, text: str) -> str:
        """The panel's line: ``text`` (what runs) while running, with a kernel compile in
        place of "starting" (the first run on a machine waits tens of seconds for it), else
        the message."""
        if self.done:
            return self.message
        compiling = compile_line()
        if compiling is not None:
            text = f"{text.removesuffix(', starting')}, {compiling}"
        return text + (", cancelling" if self.cancelling else "")


@dataclass
class WorkState(Progress):
    """What the UI shows of a job. Changed only by ``WorkerJob.poll`` (the main thread)."""

    title: str                    # what the job does, for the status bar: "dataset"
    total: int
    unit: str                     # what ``count`` counts: "poses", "frames"
    status: str = "running"       # running, completed, cancelled or failed
    count: int = 0
    eta_s: float | None = None
    cancelling: bool = False
    message: str = ""             # what happened, once done
    result: Any = None            # the work's result, once completed
    started: float = field(default_factory=time.monotonic)

    def done_of(self) -> tuple[int, int]:
        return self.count, self.total

    def line(self) -> str:
        """One line for the panel and the status bar."""
        text = f"{self.title}: {self.count}/{self.total} {self.unit}"
        return self._line(text + (f", ETA {duration(self.eta_s)}" if self.count
                                  else ", starting"))


class Feed:
    """Items read on the main thread, handed to the worker in order (at most ``capacity``
    waiting, which bounds the memory of what was read ahead)."""

    def __init__(self, cancel: threading.Event, capacity: int = 4) -> None:
        self._queue: queue.Queue = queue.Queue(capacity)
        self._cancel = cancel

    def full(self) -> bool:
        return self._queue.full()

    def put(self, item: Any) -> None:
        """Main thread: one more item (call only when not ``full``)."""
        self._queue.put_nowait(item)

    def fail(self, error: BaseException) -> None:
        """Main thread: reading failed; the worker raises ``error`` at its next ``get``."""
        while True:               # the worker must see it even behind a full queue
            try:
                self._queue.put_nowait(_Failure(error))
                return
            except queue.Full:
                self._queue.get_nowait()

    def get(self) -> Any:
        """Worker: the next item, waiting for it; raises JobCancelled once cancelled."""
        while True:
            if self._cancel.is_set():
                raise JobCancelled
            try:
                item = self._queue.get(timeout=0.05)
            except queue.Empty:
                continue
            if isinstance(item, _Failure):
                raise item.error
            return item


@dataclass
class _Failure:
    error: BaseException


class MainCalls:
    """Functions a worker needs run on the main thread (reading Blender where the reads
    cannot be listed ahead), run by the job's ``tick``; ``call`` waits for the result."""

    def __init__(self, cancel: threading.Event) -> None:
        self._queue: queue.Queue = queue.Queue()
        self._cancel = cancel

    def call(self, function: Callable[[], Any], always: bool = False) -> Any:
        """Worker: ``function()`` run on the main thread; raises JobCancelled once cancelled
        unless ``always`` (a clean-up that must run)."""
        done, box = threading.Event(), {}
        self._queue.put((function, done, box))
        while not done.wait(0.02):
            if self._cancel.is_set() and not always:
                raise JobCancelled
        if "error" in box:
            raise box["error"]
        return box["value"]

    def serve(self, budget_s: float) -> None:
        """Main thread: runs the waiting calls for about ``budget_s`` seconds."""
        end = time.monotonic() + budget_s
        while time.monotonic() < end:
            try:
                function, done, box = self._queue.get_nowait()
            except queue.Empty:
                return
            try:
                box["value"] = function()
            except Exception as exc:       # raised in the worker, which called it
                box["error"] = exc
            done.set()


class DirectCalls:
    """``MainCalls`` for work run in the main thread itself (background mode)."""

    @staticmethod
    def call(function: Callable[[], Any], always: bool = False) -> Any:
        return function()

    def close(self) -> None:
        """Nothing to clean up."""


Work = Callable[[Any, Callable[[int, int], None], Callable[[Any], None]], tuple[str, Any]]
"""``work(source, progress, deliver) -> (message, result)``."""


class WorkerJob:
    """``work(source, progress, deliver)`` in a worker thread (``start``) or in this thread
    (``run``, background mode), returning (message of the outcome, result).

    ``source``: what the work reads Blender through. ``run`` passes ``live()`` (it reads
    Blender itself); ``start`` passes ``feed``, which ``tick`` on the main thread fills by
    running ``reads()``: a generator that yields True after each item it put into the feed
    and False while the feed is full, or serves when it is a ``MainCalls``.
    ``progress(done, total)`` gives the progress (and raises JobCancelled once cancelled);
    ``deliver(item)`` hands a result to ``on_output(item)``, at once in ``run``, on the
    main thread's next ``tick`` in ``start``.
    """

    def __init__(self, title: str, total: int, unit: str, work: Work,
                 live: Callable[[], Any] = lambda: None, feed: Any = None,
                 reads: Callable[[], Generator[bool, None, None]] | None = None,
                 on_output: Callable[[Any], None] | None = None,
                 cancel: threading.Event | None = None) -> None:
        self.title, self.state = title, WorkState(title, total, unit)
        self._work, self._live, self.feed, self._on_output = work, live, feed, on_output
        self._cancel = cancel or threading.Event()
        self._queue: queue.Queue = queue.Queue()
        self._outputs: queue.Queue = queue.Queue()
        # A generator runs nothing until its first ``next``: ``tick`` may read ahead before
        # ``start``; ``run`` never starts it.
        self._reads: Iterator[bool] | None = None if reads is None else reads()
        self._thread: threading.Thread | None = None

    def run(self) -> WorkState:
        """Does the work in this thread, reading Blender directly; returns the final state."""
        source = self._live()
        try:
            self._execute(source, self._output_now)
        finally:
            if source is not None:
                source.close()
        return self.poll()

    def start(self) -> None:
        """Starts the worker thread; the main thread must ``tick`` while it runs."""
        self._thread = threading.Thread(target=self._execute,
                                        args=(self.feed, self._outputs.put),
                                        name=f"vdnif-{self.title}", daemon=True)
        self._thread.start()

    def tick(self, budget_s: float = 0.05) -> None:
        """Main thread: reads ahead for the worker for about ``budget_s`` seconds, and
        hands the delivered results to ``on_output``. A failed read fails the job."""
        self._drain(budget_s)
        if isinstance(self.feed, MainCalls):     # served until the worker ends: clean-ups
            self.feed.serve(budget_s)
        if self._reads is None:
            return
        if self._cancel.is_set() or (self._thread is not None and not self._thread.is_alive()):
            self.close()
            return
        end = time.monotonic() + budget_s
        try:
            while time.monotonic() < end and next(self._reads):
                pass
        except StopIteration:
            self._reads = None
        except Exception as exc:   # the scene changed under the job: end it, not Blender
            self.feed.fail(exc if isinstance(exc, VDNIFError) else VDNIFError(
                f"reading the scene failed: {type(exc).__name__}: {exc}"))
            self.close()

    def close(self) -> None:
        """Main thread: hands over the last results and ends the reads (their ``finally``
        cleans up what they made). Call it once the job is done."""
        self._drain()
        reads, self._reads = self._reads, None
        if reads is not None:
            try:
                reads.close()
            except Exception:   # noqa: BLE001 - what they made went with its file already
                pass

    def _drain(self, budget_s: float | None = None) -> None:
        """Hands the delivered results to ``on_output``, for about ``budget_s`` seconds
        (None: all of them)."""
        end = None if budget_s is None else time.monotonic() + budget_s
        while end is None or time.monotonic() < end:
            try:
                item = self._outputs.get_nowait()
            except queue.Empty:
                return
            self._on_output(item)

    def cancel(self) -> None:
        self._cancel.set()
        self.state.cancelling = not self.state.done

    @property
    def cancelled(self) -> threading.Event:
        return self._cancel

    def poll(self) -> WorkState:
        """Applies the queued progress and outcome to ``state`` and returns it."""
        while True:
            try:
                kind, payload = self._queue.get_nowait()
            except queue.Empty:
                return self.state
            self._apply(kind, payload)

    def join(self, timeout: float | None = None) -> WorkState:
        """Waits for the worker, ticking when called from the thread that started it
        (tests, unregistering); returns the final ``poll()``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while self._thread is not None and self._thread.is_alive():
            if deadline is not None and time.monotonic() > deadline:
                break
            self.tick()
            self._thread.join(0.02)
        self.close()
        return self.poll()

    def _output_now(self, item: Any) -> None:
        if self._on_output is not None:
            self._on_output(item)

    def _progress(self, done: int, total: int) -> None:
        if self._cancel.is_set():
            raise JobCancelled
        self._queue.put(("progress", (done, total, time.monotonic())))

    def _execute(self, source: Any, deliver: Callable[[Any], None]) -> None:
        """The work and its outcome, queued; never raises."""
        try:
            message, result = self._work(source, self._progress, deliver)
            self._queue.put(("completed", (message, result)))
        except JobCancelled:
            self._queue.put(("cancelled", None))
        except VDNIFError as exc:
            self._queue.put(("failed", str(exc)))
        except Exception as exc:   # torch errors (out of memory, ...) end the job, not Blender
            self._queue.put(("failed", f"{self.state.title} failed: {type(exc).__name__}: "
                                       f"{exc}"))

    def _apply(self, kind: str, payload: Any) -> None:
        state = self.state
        if kind == "progress":
            done, total, now = payload
            state.count, state.total = done, total
            elapsed = now - state.started
            state.eta_s = elapsed / done * (total - done) if done else None
            return
        state.status, state.cancelling = kind, False
        if kind == "failed":
            state.message = payload
        elif kind == "cancelled":
            state.message = f"{state.title} cancelled after {state.count} {state.unit}"
        else:
            state.message, state.result = payload
