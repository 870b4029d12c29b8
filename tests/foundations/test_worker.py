"""The UI's worker jobs without Blender: progress with an ETA, cancel, failures, the feed of
items read on the main thread, results handed back to it, and the same work run in the
calling thread (background mode)."""

import threading
import time

import pytest

from vdnif_addon.errors import VDNIFError
from vdnif_addon.worker import Feed, JobCancelled, WorkerJob, WorkState, duration


def fed_job(items, work, capacity=2, on_output=None):
    """A job whose reads put ``items`` into a feed (recording what the main thread read)."""
    cancel = threading.Event()
    feed = Feed(cancel, capacity)
    read = []

    def reads():
        try:
            for item in items:
                while feed.full():
                    yield False
                read.append(item)
                feed.put(item)
                yield True
        finally:
            read.append("closed")

    job = WorkerJob("sum", len(items), "items", work, live=lambda: None, feed=feed,
                    reads=reads, on_output=on_output, cancel=cancel)
    return job, read


def summing(source, progress, deliver):
    total = 0
    for done in range(1, 6):
        value = source.get()
        total += value
        deliver(total)
        progress(done, 5)
    return f"sum {total}", total


def test_the_worker_computes_what_the_main_thread_reads_and_hands_results_back():
    outputs = []
    job, read = fed_job([1, 2, 3, 4, 5], summing, on_output=outputs.append)
    main = threading.get_ident()
    job._on_output = lambda item: outputs.append((item, threading.get_ident() == main))
    job.start()
    state = job.join(timeout=30)
    assert state.status == "completed" and state.result == 15 and state.message == "sum 15"
    assert state.count == state.total == 5 and state.eta_s == 0 and state.fraction == 1
    assert outputs == [(1, True), (3, True), (6, True), (10, True), (15, True)], (
        "every result reached on_output on the main thread, in order")
    assert read == [1, 2, 3, 4, 5, "closed"]


def test_reads_stay_at_most_the_feed_capacity_ahead():
    job, read = fed_job(list(range(10)), summing, capacity=3)
    for _ in range(5):
        job.tick()
    assert read == [0, 1, 2], "the main thread reads ahead only while the feed has room"
    job.cancel()
    job.start()
    state = job.join(timeout=30)
    assert state.status == "cancelled" and read[-1] == "closed"
    assert state.message == "sum cancelled after 0 items"


def test_cancel_stops_at_the_next_progress_and_ends_the_reads():
    release = threading.Event()

    def slow(source, progress, deliver):
        for done in range(1, 1000):
            source.get()
            release.wait(5)
            progress(done, 1000)
        return "never", None

    job, read = fed_job(list(range(1000)), slow)
    job.start()
    job.tick()
    job.cancel()
    assert job.state.cancelling and job.state.line().endswith("cancelling")
    release.set()
    state = job.join(timeout=30)
    assert state.status == "cancelled" and not state.cancelling and read[-1] == "closed"
    assert len(read) < 10, "reading stopped with the job"


def test_a_failed_read_fails_the_job_with_its_message():
    cancel = threading.Event()
    feed = Feed(cancel, 1)

    def reads():
        feed.put(1)
        yield True
        raise VDNIFError("'Arm' was deleted")

    def work(source, progress, deliver):
        source.get()
        source.get()
        return "never", None

    job = WorkerJob("dataset", 2, "poses", work, feed=feed, reads=reads, cancel=cancel)
    job.start()
    state = job.join(timeout=30)
    assert state.status == "failed" and state.message == "'Arm' was deleted"
    assert state.line() == "'Arm' was deleted"


def test_errors_of_the_work_end_the_job_not_the_caller():
    def broken(source, progress, deliver):
        raise MemoryError("out of memory")

    job = WorkerJob("evaluation", 3, "poses", broken)
    job.start()
    state = job.join(timeout=30)
    assert state.status == "failed"
    assert state.message == "evaluation failed: MemoryError: out of memory"


def test_run_does_the_same_work_in_this_thread_with_the_live_source():
    closed, outputs = [], []

    class Live:
        def __init__(self):
            self.values = iter([5, 4, 3, 2, 1])

        def get(self):
            return next(self.values)

        def close(self):
            closed.append(True)

    job = WorkerJob("sum", 5, "items", summing, live=Live, on_output=outputs.append)
    state = job.run()
    assert state.status == "completed" and state.result == 15
    assert outputs == [5, 9, 12, 14, 15] and closed == [True]


def test_eta_from_the_progress_so_far():
    state = WorkState("dataset", 10, "poses", started=time.monotonic() - 4.0)
    job = WorkerJob("dataset", 10, "poses", summing)
    job.state = state
    job._apply("progress", (2, 10, state.started + 4.0))
    assert state.eta_s == pytest.approx(16.0) and state.fraction == 0.2
    assert state.line() == "dataset: 2/10 poses, ETA 16 s"
    assert WorkState("render", 3, "frames").line() == "render: 0/3 frames, starting"
    assert duration(75) == "1:15" and duration(None) == "?"


def test_a_cancelled_feed_raises_for_the_worker():
    cancel = threading.Event()
    feed = Feed(cancel)
    cancel.set()
    with pytest.raises(JobCancelled):
        feed.get()
