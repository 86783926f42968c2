"""The time a simulated drive feels: SYNC timestamps, its cycle, late and missing SYNCs.

Two kinds of drive (``SyncSettings.own_cycle``):

- SYNC-triggered (default): the drive runs one position cycle per SYNC, whenever it comes
  (it interpolates each set-point step over its cycle period and then waits for the next);
- own cycle: the drive runs its own position cycle of period T (0x60C2, else 0x1006)
  phase-locked onto SYNC (Kollmorgen AKD, Infranor, Nanotec). When a SYNC comes later than
  T + ``late_tolerance``·T after the previous one, the drive's cycle has run without it
  ("missed tick"): it holds or extrapolates its set-point for that cycle, and the late SYNC
  then re-phases the cycle. The servo is stepped once per cycle, so the time that really
  passed shows as the number of cycles (a SYNC 2 T late: three cycles).

Both judge the SYNC interval (statusword bit 8 = synchronised) and may fault on sync loss.

Pure arithmetic on timestamps (seconds, any monotonic base): the drive passes them in, so
tests inject a clock instead of widening tolerances.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class MissingSetpoint(enum.Enum):
    """What a drive does in a cycle without a fresh set-point (a late SYNC, a lost RPDO)."""

    HOLD = "hold"  # keep the last set-point: the motor stops (stop-and-go)
    EXTRAPOLATE = "extrapolate"  # continue with the last set-point step: the motor overshoots a stop


@dataclass(frozen=True)
class SyncSettings:
    """How a drive judges the SYNC it is locked onto (a per-drive setting, like real drives').

    ``missing_setpoint``: hold or extrapolate in a cycle without a fresh set-point.
    ``own_cycle``: the drive runs its own cycle locked onto SYNC (see the module doc; default:
    one cycle per SYNC). ``lock_tolerance``: an interval within (1 ± lock_tolerance)·T counts as on time
    (statusword bit 8 is set after ``lock_intervals`` such intervals in a row, cleared by
    one outside). ``late_tolerance``: a SYNC later than (1 + late_tolerance)·T means the
    drive's cycle ran without it. ``loss_periods``: sync-loss fault (EMCY 0x8700) when no
    SYNC came for this many periods while OPERATION ENABLED in IP/CSP (None: no fault).
    """

    missing_setpoint: MissingSetpoint = MissingSetpoint.HOLD
    own_cycle: bool = False
    lock_tolerance: float = 0.05
    lock_intervals: int = 2
    late_tolerance: float = 0.25
    loss_periods: float | None = None

    def __post_init__(self) -> None:
        if not 0 < self.lock_tolerance < 1 or not 0 < self.late_tolerance < 1:
            raise ValueError("lock_tolerance and late_tolerance must be in (0, 1)")
        if self.lock_intervals < 1:
            raise ValueError("lock_intervals must be >= 1")
        if self.loss_periods is not None and not self.loss_periods >= 1:
            raise ValueError("loss_periods must be >= 1 (or None to disable the sync-loss fault)")


@dataclass(frozen=True)
class SyncTiming:
    """One SYNC as the drive saw it."""

    time_s: float
    interval_s: float  # since the previous SYNC (nan for the first)
    missed_ticks: int  # drive cycles that ran without a SYNC before this one (own-cycle drives)


def missed_ticks(interval_s: float, period_s: float, late_tolerance: float) -> int:
    """Cycles of period T that ran between two SYNCs ``interval_s`` apart: the n >= 1 with
    n·T + late_tolerance·T < interval, i.e. ceil(interval/T - late_tolerance) - 1."""
    if period_s <= 0 or not interval_s > 0:
        return 0
    return max(0, math.ceil(interval_s / period_s - late_tolerance) - 1)


class SyncMonitor:
    """Timestamps SYNCs, counts missed ticks, tracks lock (bit 8) and the sync-loss deadline."""

    def __init__(self, settings: SyncSettings) -> None:
        self.settings = settings
        self.reset()

    def reset(self) -> None:
        """Forget the SYNC history (entering OPERATIONAL, reset)."""
        self.last_sync_s: float | None = None
        self.measured_period_s = 0.0
        self._good_intervals = 0
        self.locked = False
        self.loss_reported = False

    def on_sync(self, now_s: float, period_s: float) -> SyncTiming:
        """Account for a SYNC at ``now_s`` with the drive's cycle ``period_s`` (0: unknown)."""
        last, self.last_sync_s = self.last_sync_s, now_s
        self.loss_reported = False
        if last is None:
            return SyncTiming(now_s, math.nan, 0)
        interval = now_s - last
        self.measured_period_s = interval
        settings = self.settings
        on_time = period_s > 0 and abs(interval - period_s) <= settings.lock_tolerance * period_s
        self._good_intervals = self._good_intervals + 1 if on_time else 0
        self.locked = self._good_intervals >= settings.lock_intervals
        missed = missed_ticks(interval, period_s, settings.late_tolerance) if settings.own_cycle else 0
        return SyncTiming(now_s, interval, missed)

    def loss_deadline(self, period_s: float) -> float:
        """When the sync-loss fault is due (inf if disabled, not armed or already reported)."""
        periods = self.settings.loss_periods
        if periods is None or self.last_sync_s is None or period_s <= 0 or self.loss_reported:
            return math.inf
        return self.last_sync_s + periods * period_s

    def lost(self, now_s: float, period_s: float) -> bool:
        """True once when no SYNC came for ``loss_periods`` periods; the lock is lost too."""
        if now_s < self.loss_deadline(period_s):
            return False
        self.loss_reported = True
        self.locked = False
        self._good_intervals = 0
        return True
