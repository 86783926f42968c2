"""Absolute-deadline timing of the cyclic loop and its lateness statistics.

Deadlines are t_k = t_0 + k·T on ``time.perf_counter`` (never 'now + T', so errors do not
accumulate). The loop sleeps until ``spin_s`` before the deadline and spins the rest only if
the sleep woke early. A cycle whose deadline passed by more than one period is *missed*:
the grid moves on by whole periods (no burst of catch-up SYNCs, which a drive would see as
a jump) and the set-point sequence simply continues: nothing is dropped or repeated.
"""

from __future__ import annotations

import bisect
import itertools
import time

# lateness histogram: 1 µs bins up to 1 ms, then 100 µs bins up to 100 ms (last bin: later)
_FINE_S, _N_FINE = 1e-6, 1000
_COARSE_S, _N_COARSE = 1e-4, 990


def wait_until(deadline: float, spin_s: float) -> float:
    """Sleep/spin until ``deadline`` (perf_counter seconds); return the time woken."""
    now = time.perf_counter()
    remaining = deadline - now
    if remaining > spin_s:
        time.sleep(remaining - spin_s)
        now = time.perf_counter()
    while now < deadline:
        now = time.perf_counter()
    return now


class LatenessStats:
    """Histogram of lateness (2000 bins, fine below 1 ms); no allocation per sample."""

    def __init__(self, late_threshold_s: float) -> None:
        self.hist = [0] * (_N_FINE + _N_COARSE)
        self.count = 0
        self.late = 0
        self.missed = 0
        self.max_s = 0.0
        self.late_threshold_s = late_threshold_s

    def add(self, lateness_s: float, missed: bool) -> None:
        if lateness_s < _N_FINE * _FINE_S:
            b = int(lateness_s / _FINE_S) if lateness_s > 0.0 else 0
        else:
            b = _N_FINE + int((lateness_s - _N_FINE * _FINE_S) / _COARSE_S)
            if b >= _N_FINE + _N_COARSE:
                b = _N_FINE + _N_COARSE - 1
        self.hist[b] += 1
        self.count += 1
        if lateness_s > self.late_threshold_s:
            self.late += 1
        if missed:
            self.missed += 1
        if lateness_s > self.max_s:
            self.max_s = lateness_s

    def percentile_s(self, q: float) -> float:
        """Upper edge of the bin holding the q-quantile (0 < q <= 1): the first bin whose running
        count reaches q * count (running sums and the search in C: a status read asks for two)."""
        if self.count == 0:
            return 0.0
        running = list(itertools.accumulate(self.hist))  # the cycle thread may add meanwhile
        b = bisect.bisect_left(running, q * self.count)
        if b >= len(running):
            return self.max_s
        if b < _N_FINE:
            return (b + 1) * _FINE_S
        return _N_FINE * _FINE_S + (b - _N_FINE + 1) * _COARSE_S


class DeadlineGrid:
    """t_k = t_0 + k·T with whole-period shifts after a missed cycle."""

    def __init__(self, period_s: float, start_s: float, missed_after_s: float | None = None) -> None:
        self.period_s = period_s
        self.next_s = start_s
        # loop SYNC: a cycle is missed when later than one period; kernel SYNC half a cycle
        # before our RPDOs: later than half a period means they crossed the next SYNC
        self.missed_after_s = period_s if missed_after_s is None else missed_after_s

    def advance(self, woke_s: float) -> tuple[float, bool]:
        """Consume the current deadline; return (lateness, missed) and set the next deadline."""
        deadline = self.next_s
        lateness = woke_s - deadline
        missed = lateness > self.missed_after_s
        if lateness > self.period_s:
            deadline += int(lateness / self.period_s) * self.period_s
        self.next_s = deadline + self.period_s
        return lateness, missed
