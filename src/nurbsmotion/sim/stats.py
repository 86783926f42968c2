"""Counters of a simulated drive, and the judgement of a set-point stream from its timeline
(late/early SYNCs, cycles without SYNC, missing and repeated set-points), for tests that
assert a stream never stopped and went again."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nurbsmotion.sim.recording import SetpointSource


@dataclass
class DriveStats:
    """Counts since the drive was created."""

    syncs: int = 0  # SYNCs taken in OPERATIONAL (counted once the SYNC's TPDOs are out)
    syncs_ignored: int = 0
    rpdos_received: int = 0
    rpdos_dropped: int = 0
    rpdos_overwritten: int = 0  # a synchronous RPDO replaced by a newer one before the SYNC
    rpdo_length_errors: int = 0
    pdo_values_refused: int = 0  # e.g. an unsupported mode written by RPDO
    setpoints_applied: int = 0
    setpoints_ignored: int = 0  # received while not enabled / not in the mode
    setpoints_refused: int = 0  # outside the software position limits
    setpoints_missing: int = 0  # cycles in IP/CSP without a fresh set-point (held or extrapolated)
    syncs_late: int = 0  # SYNCs after which the drive's cycle had run without a SYNC
    ticks_missed: int = 0  # drive cycles that ran without a SYNC
    sync_losses: int = 0  # sync-loss faults (no SYNC for loss_periods)
    sync_length_errors: int = 0  # SYNC with a length that does not fit 0x1019 (EMCY 0x8240)
    sync_counter_jumps: int = 0  # SYNC counter not the previous + 1 (0x1019 > 0)
    rpdos_outside_window: int = 0  # synchronous RPDOs after the 0x1007 window: discarded
    rpdo_timeouts: int = 0  # RPDO event timer (0x14xx:05) expiries (EMCY 0x8250)
    tpdos_sent: int = 0
    emcys_sent: int = 0
    heartbeats_sent: int = 0


@dataclass(frozen=True)
class StreamReport:
    """How a set-point stream reached one drive, from its SYNC timeline (``stream_report``).

    A SYNC is late when its interval exceeds (1 + tolerance)·T and early below (1 - tolerance)·T
    (a cycle 0.9 T late gives the next one 0.1 T: both show). ``missed_cycles`` counts drive
    cycles that ran without a SYNC, ``missing_setpoints`` the cycles between the first and the
    last fresh set-point that held or extrapolated instead, ``repeated_setpoints`` the fresh
    set-points that repeat the previous one inside a motion (a one-cycle pause between two
    steps of ``min_step_counts`` or more in the same direction: the master sent a stale one).
    """

    period_s: float
    syncs: int
    interval_min_s: float
    interval_max_s: float
    interval_p99_s: float
    late_syncs: int
    early_syncs: int
    missed_cycles: int
    sync_index_gaps: int  # SYNCs the drive never saw (ignored, or its recording was cleared)
    missing_setpoints: int
    repeated_setpoints: int
    max_following_error_counts: int

    @property
    def clean(self) -> bool:
        """No late, early or missed cycle, no missing or repeated set-point."""
        return not self.problems()

    def problems(self) -> list[str]:
        """One line per kind of harm found (empty when the stream was clean)."""
        counts = {
            "late SYNC": self.late_syncs, "early SYNC": self.early_syncs, "drive cycle without SYNC": self.missed_cycles,
            "gap in SYNC index": self.sync_index_gaps, "cycle without fresh set-point": self.missing_setpoints,
            "repeated set-point": self.repeated_setpoints,
        }
        lines = [f"{n} x {what}" for what, n in counts.items() if n]
        if lines:
            lines.append(f"SYNC interval min {self.interval_min_s * 1e3:.3f} ms, max {self.interval_max_s * 1e3:.3f} ms "
                         f"(T = {self.period_s * 1e3:.3f} ms)")
        return lines


def stream_report(timeline: np.ndarray, period_s: float, tolerance: float = 0.05, min_step_counts: int = 2) -> StreamReport:
    """Judge a drive's ``SyncRecorder.as_array()`` against its cycle ``period_s``."""
    if timeline.shape[0] == 0:
        return StreamReport(period_s, 0, math.nan, math.nan, math.nan, 0, 0, 0, 0, 0, 0, 0)
    index, interval_ns, missed, source, demand, following = (timeline[:, k] for k in (0, 2, 3, 4, 5, 7))
    intervals_s = interval_ns[interval_ns >= 0] * 1e-9
    fresh_rows = np.flatnonzero(source == SetpointSource.FRESH)
    inside = slice(fresh_rows[0], fresh_rows[-1] + 1) if len(fresh_rows) else slice(0, 0)
    steps = np.diff(demand[fresh_rows]) if len(fresh_rows) > 1 else np.zeros(0, dtype=np.int64)
    return StreamReport(
        period_s=period_s,
        syncs=int(timeline.shape[0]),
        interval_min_s=float(intervals_s.min()) if len(intervals_s) else math.nan,
        interval_max_s=float(intervals_s.max()) if len(intervals_s) else math.nan,
        interval_p99_s=float(np.percentile(intervals_s, 99)) if len(intervals_s) else math.nan,
        late_syncs=int(np.count_nonzero(intervals_s > (1 + tolerance) * period_s)),
        early_syncs=int(np.count_nonzero(intervals_s < (1 - tolerance) * period_s)),
        missed_cycles=int(missed.sum()),
        sync_index_gaps=int(np.count_nonzero(np.diff(index) != 1)),
        missing_setpoints=int(np.count_nonzero(np.isin(source[inside], (SetpointSource.HELD, SetpointSource.EXTRAPOLATED)))),
        repeated_setpoints=_pauses_inside_motion(steps, min_step_counts),
        max_following_error_counts=int(np.abs(following).max()),
    )


def _pauses_inside_motion(steps: np.ndarray, min_step_counts: int) -> int:
    """Zero steps with a step of at least ``min_step_counts`` in the same direction on both
    sides: a planned motion never pauses for one cycle at speed."""
    if len(steps) < 3:
        return 0
    before, now, after = steps[:-2], steps[1:-1], steps[2:]
    moving = (np.abs(before) >= min_step_counts) & (np.abs(after) >= min_step_counts) & (np.sign(before) == np.sign(after))
    return int(np.count_nonzero((now == 0) & moving))
