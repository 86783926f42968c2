"""How long this process spent in the cyclic garbage collector: seconds and collections so far,
counted by ``gc.callbacks``.

The cycle thread's watch (cycle_watch) takes the difference over an absence, so a
``cycle_thread_late`` line says whether collections filled it (``gc_ms``, ``held_by=gc``).
A collection holds the interpreter lock from start to end: no other thread of the process
runs meanwhile. Cost: two Python calls per collection (about a microsecond each; the daemon
collects its youngest generation some hundred times a second at most).
"""

from __future__ import annotations

import gc
import threading
import time
from typing import Any, Callable

FULL_GENERATION = 2


class GcClock:
    """Time spent in collections since :meth:`install` (``clock``: injectable for tests)."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self._started_s = -1.0
        self.total_s = 0.0  # seconds in collections so far
        self.collections = 0  # collections finished so far, every generation
        self.full_collections = 0  # of them, full (generation 2)

    def on_gc(self, phase: str, info: dict[str, Any]) -> None:
        """The ``gc.callbacks`` entry: time from 'start' to 'stop'."""
        if phase == "start":
            self._started_s = self._clock()
            return
        if self._started_s < 0:  # installed during a collection
            return
        self.total_s += self._clock() - self._started_s
        self._started_s = -1.0
        self.collections += 1
        if info.get("generation") == FULL_GENERATION:
            self.full_collections += 1

    def install(self) -> None:
        if self.on_gc not in gc.callbacks:
            gc.callbacks.append(self.on_gc)

    def remove(self) -> None:
        if self.on_gc in gc.callbacks:
            gc.callbacks.remove(self.on_gc)


_PROCESS_CLOCK: GcClock | None = None
_LOCK = threading.Lock()


def process_gc_clock() -> GcClock:
    """The process' one installed GcClock (installed at the first call)."""
    global _PROCESS_CLOCK
    with _LOCK:
        if _PROCESS_CLOCK is None:
            _PROCESS_CLOCK = GcClock()
            _PROCESS_CLOCK.install()
        return _PROCESS_CLOCK


def process_gc_s() -> float:
    """Seconds this process spent in collections since the first call of process_gc_clock()."""
    return process_gc_clock().total_s


__all__ = ["GcClock", "process_gc_clock", "process_gc_s"]
