"""Why the cycle thread came back late: one ``cycle_thread_late`` log line naming what held it.

With the kernel queue (fieldbus/bcm_queue.py) the cycle thread wakes every few cycles and
the kernel sends SYNC meanwhile; the queue holds 64 cycles for 3 axes (256 ms at T = 4 ms,
64 ms at 1 ms). A thread away longer ends the job in a ``stall`` fault. When it comes back
more than ``threshold_s`` after its previous wake-up (the writer passes half the queue; its
lateness alone also counts the catch-up wake-ups after one late one), this says from three
measurements
what kept it away, so an integrator knows what to fix on the machine:

- ``held_by=gc``: the process' garbage collections (gc_clock) took at least half the gap:
  a collection holds the interpreter lock throughout.
- ``held_by=thread:<name>``: this process ran meanwhile (process CPU >= half the gap), so
  another of its threads held the interpreter lock; the busiest thread of the last second
  (per-thread CPU from /proc/self/task) is named.
- ``held_by=other_work``: the process got little CPU while the kernel went on sending SYNC
  (SYNCs echoed x T >= half the gap, or the queue ran out): the CPU went to other
  processes, or a hypervisor / the host of a User-Mode Linux guest did not run this
  process (docs/vcan.md, "The vcan lane and the host's scheduler").
- ``held_by=machine``: the kernel sent no SYNC for most of the gap either: the whole
  machine (or virtual machine) stood still.

The figures come with it: ``late_ms`` (after the wake-up's deadline), ``away_ms`` (since the
previous wake-up), ``wire_cycles`` (SYNCs sent meanwhile), ``process_cpu_ms``, ``gc_ms`` (time in collections). At most one
line a second (the others are counted in ``suppressed=``). Cost per wake-up: one read of
the process CPU clock; the per-thread figures are read once a second and after a late wake-up.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import Callable

from nurbsmotion.gc_clock import process_gc_s
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

THREAD_SAMPLE_PERIOD_S = 1.0  # per-thread CPU is sampled this often (the 'busiest thread' window)
LOG_EVERY_S = 1.0  # at most one line this often
HELD_SHARE = 0.5  # share of the gap that counts as "this process ran" / "the kernel kept sending"

ThreadCpu = dict[str, float]  # thread name -> CPU seconds used so far


def threads_cpu_s() -> ThreadCpu:
    """CPU seconds of every thread of this process by its Python name (native id if unknown):
    /proc/self/task/<tid>/schedstat (ns) where present, else utime + stime of its stat."""
    names = {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}
    result: ThreadCpu = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return result
    ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    for tid in tids:
        name = names.get(int(tid), f"tid{tid}")
        try:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                result[name] = int(f.read().split()[0]) * 1e-9
            continue
        except (OSError, ValueError, IndexError):
            pass
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            result[name] = (int(fields[11]) + int(fields[12])) / ticks
        except (OSError, ValueError, IndexError):
            continue
    return result


@dataclass(frozen=True)
class LateWake:
    """One late wake-up of the cycle thread, and what held it (module docstring)."""

    late_s: float
    away_s: float
    wire_cycles: int
    process_cpu_s: float
    queue_ran_out: bool
    held_by: str
    gc_s: float = 0.0

    def message(self, suppressed: int) -> str:
        return kv("cycle_thread_late", late_ms=round(self.late_s * 1e3, 1), away_ms=round(self.away_s * 1e3, 1),
                  wire_cycles=self.wire_cycles, process_cpu_ms=round(self.process_cpu_s * 1e3, 1),
                  gc_ms=round(self.gc_s * 1e3, 1), queue_ran_out=self.queue_ran_out, held_by=self.held_by,
                  suppressed=suppressed)


def held_by(away_s: float, process_cpu_s: float, wire_cycles: int, period_s: float, queue_ran_out: bool,
            busiest_thread: str, gc_s: float = 0.0) -> str:
    """What kept the cycle thread away for ``away_s`` (module docstring)."""
    if gc_s >= HELD_SHARE * away_s:
        return "gc"
    if process_cpu_s >= HELD_SHARE * away_s:
        return f"thread:{busiest_thread or 'unknown'}"
    if queue_ran_out or wire_cycles * period_s >= HELD_SHARE * away_s:
        return "other_work"
    return "machine"


def busiest(before: ThreadCpu, after: ThreadCpu, exclude: str) -> str:
    """Name of the thread that used the most CPU between two samples (``exclude`` left out)."""
    best, best_s = "", -1.0
    for name, cpu_s in after.items():
        used = cpu_s - before.get(name, 0.0)
        if name != exclude and used > best_s:
            best, best_s = name, used
    return best


class CycleWatch:
    """Called by the cycle writer at every wake-up; logs ``cycle_thread_late`` (module docstring).
    Clocks and the per-thread sampler are injectable (tests)."""

    def __init__(self, period_s: float, threshold_s: float, clock: Callable[[], float] = time.monotonic,
                 process_cpu: Callable[[], float] = time.process_time,
                 threads_cpu: Callable[[], ThreadCpu] = threads_cpu_s, own_name: str = "nurbsmotion-cycle",
                 gc_time: Callable[[], float] = process_gc_s) -> None:
        self.period_s = period_s
        self.threshold_s = threshold_s
        self._clock = clock
        self._process_cpu = process_cpu
        self._threads_cpu = threads_cpu
        self._own_name = own_name
        self._gc_time = gc_time
        self._last_gc_s = gc_time()  # the process' collections are timed from here on (gc_clock)
        self._last_wake_s = -1.0
        self._last_cpu_s = 0.0
        self._threads: ThreadCpu = {}
        self._threads_at_s = -1.0
        self._logged_at_s = float("-inf")
        self.suppressed = 0
        self.late_wakes = 0

    def woke(self, late_s: float, wire_cycles: int, queue_ran_out: bool = False) -> LateWake | None:
        """One wake-up, ``late_s`` after its deadline, ``wire_cycles`` SYNCs sent since the
        previous one; a LateWake (also logged, at most once a second) when the thread was
        away longer than ``threshold_s``, else None."""
        now, cpu, gc_s = self._clock(), self._process_cpu(), self._gc_time()
        away, used, collecting = now - self._last_wake_s, cpu - self._last_cpu_s, gc_s - self._last_gc_s
        first = self._last_wake_s < 0
        self._last_wake_s, self._last_cpu_s, self._last_gc_s = now, cpu, gc_s
        if first or away <= self.threshold_s:  # away, not late: a wake-up after a late one is late too
            if now - self._threads_at_s >= THREAD_SAMPLE_PERIOD_S:
                self._threads, self._threads_at_s = self._threads_cpu(), now
            return None
        self.late_wakes += 1
        threads = self._threads_cpu()
        culprit = busiest(self._threads, threads, self._own_name)
        self._threads, self._threads_at_s = threads, now
        wake = LateWake(late_s, away, wire_cycles, used, queue_ran_out,
                        held_by(away, used, wire_cycles, self.period_s, queue_ran_out, culprit, collecting), collecting)
        if now - self._logged_at_s >= LOG_EVERY_S:
            log.warning(wake.message(self.suppressed))
            self._logged_at_s, self.suppressed = now, 0
        else:
            self.suppressed += 1
        return wake


__all__ = ["CycleWatch", "LateWake", "held_by", "busiest", "threads_cpu_s"]
