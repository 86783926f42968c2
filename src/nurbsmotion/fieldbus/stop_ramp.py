"""Controlled stop on the path by time-scaling the remaining planned set-points.

Playback position s (a fractional index into the planned rows) advances by a rate r per
cycle; r ramps from 1 to 0 by ``dr`` per cycle and set-points are interpolated linearly
between rows i = floor(s) and i + 1. An axis moving |Δc| counts per planned cycle moves
r·|Δc| counts per cycle, so the ramp adds a deceleration of |Δc|·dr / T² counts/s².
Choosing dr = min_j a_j·T² / max|Δc_j| keeps that extra deceleration within every
axis' a_max (the path's own curvature accelerations scale with r² <= 1). The positions
stay on the planned polyline, so the stop stays on the path.

The same playback carries the feed override: while streaming, r moves towards the requested
rate by RATE_RAMP_SHARE of the stop slope per cycle, so a rate change adds at most
RATE_RAMP_SHARE·a_max; at r = 1 every cycle sends exactly the next planned row.
"""

from __future__ import annotations

import numpy as np

RATE_RAMP_SHARE = 0.25  # share of each axis' a_max a change of the playback rate may add


def ramp_slope(counts: np.ndarray, accel_counts_s2: np.ndarray, period_s: float) -> float:
    """dr per cycle (0 < dr <= 1) from the largest per-cycle step of each axis."""
    if len(counts) < 2:
        return 1.0
    max_step = np.abs(np.diff(np.asarray(counts, dtype=np.int64), axis=0)).max(axis=0).astype(float)
    return slope_of_steps(max_step.tolist(), [float(a) for a in accel_counts_s2], period_s)


def slope_of_steps(max_step_counts: list[float], accel_counts_s2: list[float], period_s: float) -> float:
    """dr = min(1, min_j a_j·T² / max|Δc_j|) over the axes that move (module docstring)."""
    dr = 1.0
    for step, accel in zip(max_step_counts, accel_counts_s2):
        if step > 0:
            dr = min(dr, accel * period_s**2 / step)
    return dr


def stop_slope(max_step_counts: list[float], planned_accel_counts_s2: list[float], accel_limit_counts_s2: list[float],
               period_s: float, rate: float, fallback: float) -> float:
    """Rate decrease per cycle for a controlled stop started at playback rate ``rate``.

    The stop ramp adds |Δc_j|·dr/T² to axis j on top of the plan's own acceleration, which
    at rate r is r²·a_planned_j; keeping the sum within a_max_j gives
    dr = min_j (a_max_j - r²·a_planned_j)·T² / max|Δc_j| (ramp_slope uses a_max_j alone, so
    a stop during the plan's deceleration would exceed the limit). Never below 10 % of
    ``fallback`` (ramp_slope), so a stop always ends, and never above it.
    """
    dr = fallback
    for step, planned, limit in zip(max_step_counts, planned_accel_counts_s2, accel_limit_counts_s2):
        if step > 0:
            room = limit - rate * rate * planned
            dr = min(dr, room * period_s * period_s / step)
    return max(dr, 0.1 * fallback)


def setpoints_at(rows: memoryview, s: float, out: list[int], n_axes: int) -> None:
    """Write into ``out`` the set-points at fractional row ``s``: linear between rows
    floor(s) and floor(s) + 1 (exactly row s when s is whole). Floats only, no allocation."""
    i = int(s)
    f = s - i
    if f > 0.0:
        for j in range(n_axes):
            a = rows[i, j]
            out[j] = int(round(a + f * (rows[i + 1, j] - a)))
    else:
        for j in range(n_axes):
            out[j] = rows[i, j]


class StopRamp:
    """Per-cycle state of a controlled stop; :meth:`step` only does float arithmetic."""

    __slots__ = ("rows", "last", "dr", "s", "r", "n_axes")

    def __init__(self, rows: memoryview, dr: float) -> None:
        """``rows``: a 2-D memoryview (cycles x axes) of int64 counts."""
        self.rows = rows
        self.last = rows.shape[0] - 1
        self.dr = dr
        self.n_axes = rows.shape[1]
        self.s = 0.0
        self.r = 0.0

    def start(self, position: float, rate: float = 1.0) -> None:
        """Begin at (fractional) row ``position``, the last set-point sent, moving at ``rate``
        rows per cycle."""
        self.s = float(min(position, self.last))
        self.r = rate

    def step(self, out: list[int]) -> bool:
        """Write the next set-points into ``out``; False once stopped (out holds the final ones)."""
        r = self.r - self.dr
        if r < 0.0:
            r = 0.0
        self.r = r
        s = self.s + r
        if s >= self.last:
            s = float(self.last)
            self.r = r = 0.0
        self.s = s
        setpoints_at(self.rows, s, out, self.n_axes)
        return r > 0.0
