"""Playback of one job's planned rows: position, rate, feed override and the stop ramp.

The playback position s is a fractional row index; each cycle it advances by the rate r
(rows per cycle) and the set-points are interpolated between rows floor(s) and floor(s)+1
(stop_ramp.setpoints_at). While playing, r moves towards the requested rate (the feed
override) by RATE_RAMP_SHARE of the stop slope per cycle, so at r = 1 each cycle sends
exactly the next planned row. A controlled stop hands (s, r) to a StopRamp, which brings r
to 0 within every axis' a_max (stop_ramp.stop_slope).

The whole state is a few floats, so the cycle writer can keep one :meth:`snapshot` per
queued cycle and :meth:`restore` it to rewrite the queue beyond its guard (stop, override).
"""

from __future__ import annotations

import math

from nurbsmotion.fieldbus.stop_ramp import RATE_RAMP_SHARE, StopRamp, setpoints_at, stop_slope

PlaybackState = tuple[float, float, float, int, bool, float, float, float]


class Playback:
    """Where a job plays now and how fast; every per-cycle method is float arithmetic only."""

    __slots__ = ("rows", "last", "n_axes", "s", "r", "target", "index", "stopping", "ramp", "ramp_dr",
                 "max_step", "planned_accel")

    def __init__(self, rows: memoryview, ramp_dr: float, rate: float, max_step: list[float],
                 planned_accel: list[float]) -> None:
        """``rows``: 2-D memoryview (cycles x axes) of int64 counts; ``ramp_dr``: ramp_slope of
        the rows; ``max_step``/``planned_accel``: per-axis largest |Δc| per cycle and planned
        acceleration (counts/s²), for the stop slope."""
        self.rows = rows
        self.last = rows.shape[0] - 1
        self.n_axes = rows.shape[1]
        self.ramp = StopRamp(rows, ramp_dr)
        self.ramp_dr = ramp_dr
        self.max_step = max_step
        self.planned_accel = planned_accel
        self.s = 0.0
        self.r = rate
        self.target = rate
        self.index = -1  # last planned row handed out (int(s)); -1 before the first
        self.stopping = False

    def advance(self, out: list[int]) -> bool:
        """Set-points of the next cycle into ``out``; True once the last row is reached."""
        if self.index < 0:
            s = 0.0
        else:
            r, target, dr = self.r, self.target, self.ramp_dr * RATE_RAMP_SHARE
            r = min(r + dr, target) if r < target else max(r - dr, target)
            self.r = r
            s = min(self.s + r, float(self.last))
        self.s = s
        setpoints_at(self.rows, s, out, self.n_axes)
        self.index = int(s)
        return self.index == self.last

    def start_stop(self, accel_limits: list[float], period_s: float) -> None:
        """Begin a controlled stop from the position and rate played last."""
        self.ramp.start(self.s, self.r)
        self.ramp.dr = stop_slope(self.max_step, self.planned_accel, accel_limits, period_s, self.r, self.ramp_dr)
        self.stopping = True

    def stop_step(self, out: list[int]) -> bool:
        """Next set-points of the stop into ``out``; False once at rest."""
        moving = self.ramp.step(out)
        self.s, self.r = self.ramp.s, self.ramp.r
        self.index = int(self.s)
        return moving

    def stop_cycles(self, accel_limits: list[float], period_s: float) -> int:
        """Cycles a controlled stop started now would take to reach rest: ceil(r / dr) + 1."""
        r = self.ramp.r if self.stopping else self.r
        if r <= 0.0:
            return 1
        dr = self.ramp.dr if self.stopping else stop_slope(self.max_step, self.planned_accel, accel_limits,
                                                           period_s, r, self.ramp_dr)
        return math.ceil(r / dr) + 1

    def snapshot(self) -> PlaybackState:
        return (self.s, self.r, self.target, self.index, self.stopping, self.ramp.s, self.ramp.r, self.ramp.dr)

    def restore(self, state: PlaybackState) -> None:
        (self.s, self.r, self.target, self.index, self.stopping, self.ramp.s, self.ramp.r, self.ramp.dr) = state
