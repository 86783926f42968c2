"""Playback of one job's planned rows: position, rate, feed override and the stop ramp.

The playback position s is a fractional row index; each cycle it advances by the rate r
(rows per cycle) and the set-points are interpolated between rows floor(s) and floor(s)+1
(stop_ramp.setpoints_at). While playing, r moves towards the requested rate (the feed
override) by RATE_RAMP_SHARE of the stop slope per cycle, so at r = 1 each cycle sends
exactly the next planned row (after a rate change or a hold s may be between rows: at r = 1
each cycle then advances by 1 - dr until s is whole again, a rate step within the same ramp
limit, so the planned rows are sent exactly again). A controlled stop hands (s, r) to a StopRamp, which brings r
to 0 within every axis' a_max (stop_ramp.stop_slope).

The whole state is a few floats, so the cycle writer can keep one :meth:`snapshot` per
queued cycle and :meth:`restore` it to rewrite the queue beyond its guard (stop, override).

Hold and resume: a hold runs the same stop ramp but the job stays (:meth:`resume` sets r = 0
and lets it ramp back up to the requested rate like an override change). Pause rows (program
M0/M1/M6, where the planner already brought the axes to rest) stop the advance exactly on
that row; resuming there restarts at the requested rate at once (the plan itself
accelerates from rest, so no extra ramp is needed).

Streamed jobs (fieldbus.row_source.RowFeed): the rows arrive in chunks while the job plays.
Each cycle the playback appends the next queued chunk to its window unless it already ran
onto the newest chunk's stop tail or a stop is under way; the stop slope's figures (largest
step and planned acceleration per axis) are running maxima over the rows received. At the
end of the rows received the playback waits there (the chunk ended at rest) or, on a stop
tail at rest, ends the job: planning fell behind (``feed.fell_behind_row``).
"""

from __future__ import annotations

import math

from typing import Any

from nurbsmotion.fieldbus.row_source import RowChunk, RowFeed
from nurbsmotion.fieldbus.stop_ramp import RATE_RAMP_SHARE, StopRamp, setpoints_at, slope_of_steps, stop_slope

PlaybackState = tuple[float, float, float, int, bool, float, float, float, int]


class Playback:
    """Where a job plays now and how fast; every per-cycle method is float arithmetic only."""

    __slots__ = ("rows", "last", "n_axes", "s", "r", "target", "index", "stopping", "ramp", "ramp_dr",
                 "max_step", "planned_accel", "pauses", "pause_i", "feed", "accel_limits", "period_s")

    def __init__(self, rows: Any, ramp_dr: float, rate: float, max_step: list[float],
                 planned_accel: list[float], pauses: tuple[int, ...] = (), feed: RowFeed | None = None,
                 accel_limits: list[float] | None = None, period_s: float = 0.0) -> None:
        """``rows``: 2-D memoryview (cycles x axes) of int64 counts, or the ``feed`` of a streamed
        job; ``ramp_dr``: ramp_slope of the rows; ``max_step``/``planned_accel``: per-axis
        largest |Δc| per cycle and planned acceleration (counts/s²), for the stop slope;
        ``pauses``: sorted row indices where the playback stops and waits for :meth:`resume`
        (program pauses, axes at rest there). A ``feed`` needs ``accel_limits`` (counts/s²)
        and ``period_s`` to lower ``ramp_dr`` as larger steps arrive."""
        self.feed = feed
        self.accel_limits = accel_limits or []
        self.period_s = period_s
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
        self.pauses = [p for p in pauses if 0 <= p < self.last]
        self.pause_i = 0  # index into pauses of the next pause row not yet reached

    @property
    def next_pause(self) -> int:
        """Row of the next program pause (the last row when none is left)."""
        return self.pauses[self.pause_i] if self.pause_i < len(self.pauses) else self.last

    def at_pause(self) -> bool:
        """True when the row handed out last is the next pause row (then :meth:`advance`
        does not move until :meth:`resume`)."""
        return self.index >= 0 and self.pause_i < len(self.pauses) and self.s == float(self.pauses[self.pause_i])

    def resume(self, rate: float) -> None:
        """Continue after a hold (r ramps up from 0 to ``rate``) or from a pause row or before
        the first row (at ``rate`` at once: the plan accelerates from rest there)."""
        from_pause = self.at_pause() or self.index < 0
        if self.at_pause():
            self.pause_i += 1
        self.stopping = False
        self.target = rate
        self.r = rate if from_pause else 0.0

    def advance(self, out: list[int]) -> bool:
        """Set-points of the next cycle into ``out``; True once the last row is reached."""
        feed = self.feed
        if feed is not None and not feed.final:
            chunk = feed.take(self.s if self.index >= 0 else -1.0, self.stopping)
            if chunk is not None:
                self._adopt(chunk, feed)
        if self.index < 0:
            s = 0.0
        else:
            r, target, dr = self.r, self.target, self.ramp_dr * RATE_RAMP_SHARE
            r = min(r + dr, target) if r < target else max(r - dr, target)
            self.r = r
            s = self.s + r
            if r == 1.0:  # back at the planned rate: slip back onto whole rows, dr per cycle at most
                f = self.s - int(self.s)
                if f > 0.0:
                    s = float(int(self.s) + 1) if f <= dr else s - dr
            s = min(s, float(self.next_pause))
        self.s = s
        setpoints_at(self.rows, s, out, self.n_axes)
        self.index = int(s)
        if self.index != self.last:
            return False
        if feed is None or feed.final:
            return True
        if self.index >= feed.planned_end:  # at rest at the end of a stop tail: planning fell behind
            feed.fell_behind_row = feed.planned_end - 1
            return True
        return False  # at rest at the end of the rows received: wait for the next chunk

    def _adopt(self, chunk: RowChunk, feed: RowFeed) -> None:
        """The window grew by ``chunk``: its last row, pauses and stop-slope figures."""
        self.last = feed.end - 1
        if not self.stopping:
            self.ramp.last = self.next_pause
        self.pauses.extend(chunk.pauses)
        for j in range(self.n_axes):
            step = chunk.max_step[j] if chunk.max_step else 0.0
            if step > self.max_step[j]:
                self.max_step[j] = step
                if self.accel_limits:
                    self.ramp_dr = min(self.ramp_dr, slope_of_steps([step], [self.accel_limits[j]], self.period_s))
            if chunk.max_accel and chunk.max_accel[j] > self.planned_accel[j]:
                self.planned_accel[j] = chunk.max_accel[j]

    def start_stop(self, accel_limits: list[float], period_s: float) -> None:
        """Begin a controlled stop from the position and rate played last."""
        self.ramp.last = self.next_pause  # a stop never runs past a program pause (at rest there)
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
        return (self.s, self.r, self.target, self.index, self.stopping, self.ramp.s, self.ramp.r, self.ramp.dr,
                self.pause_i)

    def restore(self, state: PlaybackState) -> None:
        (self.s, self.r, self.target, self.index, self.stopping, self.ramp.s, self.ramp.r, self.ramp.dr,
         self.pause_i) = state
        self.ramp.last = self.next_pause
