"""The time-optimal rest-to-rest motion along one straight block (the 1-D S-curve).

On a straight line the path adds no acceleration or jerk of its own, so the fastest motion
under |v| <= V, |a| <= A, |j| <= J is the classic 7-phase profile (ruckig's 1-D solution for
rest-to-rest): jerk +J, 0, -J (reach the peak acceleration), cruise, then the mirror image.
With t_j the jerk phases, t_a the constant-acceleration phases and t_v the cruise:

  V J >= A^2:  t_j = A / J,  t_a = V / A - A / J;  else  t_j = sqrt(V / J),  t_a = 0
  distance to reach V and stop again: D_v = V (2 t_j + t_a); cruise t_v = (D - D_v) / V.
  Shorter moves do not reach V: with t_j = A / J, D = A (t_j + t_a)(2 t_j + t_a) gives
  t_a = (sqrt(t_j^2 + 4 D / A) - 3 t_j) / 2; if that is negative A is not reached either and
  D = 2 J t_j^3.

Without a jerk limit t_j = 0 (the trapezoid). Sampled every cycle after stretching time by
k = n T / duration >= 1 (n = whole cycles): v / k, a / k^2, j / k^3. The discrete second and
third differences of a sampled motion are averages of a and j over the neighbouring cycles,
so they stay within A and J; the plan aims at ROUNDING_MARGIN of them only because the third
difference of coordinates of a few hundred mm, divided by T^3 = 1e-9 s^3, carries a rounding
error of ~1e-8 of J (measured on a 500 mm line).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

ROUNDING_MARGIN = 1.0 - 1e-6


@dataclass(frozen=True)
class SCurve:
    """Phase durations (s) and jerks (mm/s^3) of a rest-to-rest motion; constant-acceleration
    phases of a trapezoid (no jerk limit) are phases with an acceleration step at their start."""

    durations_s: tuple[float, ...]
    jerks_mm_s3: tuple[float, ...]
    start_accels_mm_s2: tuple[float | None, ...]  # acceleration set at the phase's start (trapezoid), else None

    @property
    def duration_s(self) -> float:
        return float(sum(self.durations_s))


def phase_times(distance_mm: float, v: float, a: float, j: float | None) -> tuple[float, float, float]:
    """(t_j, t_a, t_v) of the time-optimal rest-to-rest profile (module docstring)."""
    if j is None or math.isinf(j):
        t_a = min(v / a, math.sqrt(distance_mm / a))
        return 0.0, t_a, max(distance_mm - a * t_a * t_a, 0.0) / max(a * t_a, 1e-300)
    if v * j >= a * a:
        t_j, t_a = a / j, v / a - a / j
    else:
        t_j, t_a = math.sqrt(v / j), 0.0
    reach = v * (2.0 * t_j + t_a)
    if distance_mm >= reach:
        return t_j, t_a, (distance_mm - reach) / v
    t_j = a / j
    t_a = (math.sqrt(t_j * t_j + 4.0 * distance_mm / a) - 3.0 * t_j) / 2.0
    if t_a < 0.0:
        t_j, t_a = (distance_mm / (2.0 * j)) ** (1.0 / 3.0), 0.0
    return t_j, t_a, 0.0


def scurve(distance_mm: float, v: float, a: float, j: float | None) -> SCurve:
    """The rest-to-rest profile over ``distance_mm`` as phases."""
    t_j, t_a, t_v = phase_times(distance_mm, v, a, j)
    if j is None or math.isinf(j):
        peak = distance_mm / (t_a * (t_a + t_v)) if t_a > 0 else 0.0  # exact distance despite rounding
        return SCurve((t_a, t_v, t_a), (0.0, 0.0, 0.0), (peak, 0.0, -peak))
    return SCurve((t_j, t_a, t_j, t_v, t_j, t_a, t_j), (j, 0.0, -j, 0.0, -j, 0.0, j), (None,) * 7)


def positions(profile: SCurve, times_s: NDArray[np.float64]) -> NDArray[np.float64]:
    """s(t) of the profile at the given times (clamped to [0, duration])."""
    t = np.clip(times_s, 0.0, profile.duration_s)
    out = np.zeros(len(t))
    s = v = acc = start = 0.0
    for duration, jerk, set_accel in zip(profile.durations_s, profile.jerks_mm_s3, profile.start_accels_mm_s2):
        if set_accel is not None:
            acc = set_accel
        inside = (t >= start) & (t <= start + duration)
        tau = t[inside] - start
        out[inside] = s + v * tau + acc * tau**2 / 2.0 + jerk * tau**3 / 6.0
        s += v * duration + acc * duration**2 / 2.0 + jerk * duration**3 / 6.0
        v += acc * duration + jerk * duration**2 / 2.0
        acc += jerk * duration
        start += duration
    return out


def cycle_positions(profile: SCurve, distance_mm: float, period_s: float) -> NDArray[np.float64]:
    """s at every cycle of the profile stretched to a whole number of cycles; the first is 0 and
    the last exactly ``distance_mm``."""
    duration = profile.duration_s
    cycles = max(int(math.ceil(duration / period_s - 1e-9)), 1)
    s = positions(profile, np.arange(cycles + 1, dtype=np.float64) * (duration / cycles))
    s[0], s[-1] = 0.0, distance_mm
    return np.minimum(np.maximum.accumulate(s), distance_mm)
