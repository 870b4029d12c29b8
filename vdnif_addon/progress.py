"""Progress with an ETA for long batch work, printed on one updating stderr line."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Call ``update(done)``; prints ``label: done/total unit, elapsed, ETA`` at most every
    ``interval`` seconds and once at the end."""

    def __init__(self, label: str, total: int, unit: str = "", stream: TextIO | None = None,
                 interval: float = 0.5) -> None:
        self.label, self.total, self.unit = label, max(int(total), 1), unit
        # sys.stderr of now, not of the import: a caller may have replaced it since
        self.stream, self.interval = stream or sys.stderr, interval
        self.start = self._last = time.perf_counter()

    def update(self, done: int, extra: str = "") -> None:
        now = time.perf_counter()
        if done < self.total and now - self._last < self.interval:
            return
        self._last = now
        elapsed = now - self.start
        eta = elapsed / done * (self.total - done) if done else float("nan")
        line = (f"{self.label}: {done}/{self.total} {self.unit}".rstrip()
                + f", {elapsed:.1f} s, ETA {eta:.1f} s{extra}")
        end = "\n" if done >= self.total or not self.stream.isatty() else "\r"
        self.stream.write(line + end)
        self.stream.flush()
