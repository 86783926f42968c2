"""Feed override as a playback rate, and the highest rate a plan allows.

Playing the planned set-points at rate r (r planned cycles per real cycle, linear
interpolation between planned rows) gives each axis
- velocity  <= r·v_planned (the interpolation averages neighbouring steps),
- acceleration <= r²·a_planned + a_planned/4 + a_ramp:
  r² from the time scaling; a_planned/4 the most the piecewise-linear interpolation of the
  rows adds (its error is within [0, a T²/8] and a second difference combines three such
  errors); a_ramp while the rate changes (RAMP_SHARE of the axis limit, see fieldbus.stop_ramp).
So the highest rate that keeps the axis limits is
    r_max = min(1.5, min_j v_max_j / v_planned_j,
                min_j sqrt(((1 - RAMP_SHARE)·a_max_j - a_planned_j/4) / a_planned_j)),
the issue's min(1.5, sqrt(a_max/a_planned), v_max/v_planned) with room for the two extra
terms (without it a 150 % request measured 2375 mm/s² on a 2000 mm/s² axis). Overrides at
or below 100 % are used as asked; above they are clamped to max(1, r_max).
"""

from __future__ import annotations

import math

import numpy as np

from nurbsmotion.fieldbus.stop_ramp import RATE_RAMP_SHARE as RAMP_SHARE  # a rate change's share of a_max

MAX_OVERRIDE = 1.5
INTERPOLATION_SHARE = 0.25  # a_planned share the linear interpolation between rows may add


def max_rate(v_planned: np.ndarray, a_planned: np.ndarray, v_max: list[float | None],
             a_max: list[float | None]) -> float:
    """r_max of the module docstring (axes without a limit or without motion do not bound it)."""
    rate = MAX_OVERRIDE
    for vp, ap, vm, am in zip(v_planned, a_planned, v_max, a_max):
        if vm is not None and vp > 0:
            rate = min(rate, vm / vp)
        if am is not None and ap > 0:
            room = (1.0 - RAMP_SHARE) * am - INTERPOLATION_SHARE * ap
            rate = min(rate, math.sqrt(room / ap) if room > 0 else 0.0)
    return float(rate)


def effective_rate(requested: float, rate_limit: float) -> float:
    """The rate actually used for an override request (fractions, 1.0 = 100 %)."""
    if requested <= 1.0:
        return requested
    return min(requested, max(1.0, rate_limit))
