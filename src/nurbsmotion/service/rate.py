"""Feed override as a playback rate, and the highest rate a plan allows.

Playing the planned set-points at rate r (r planned cycles per real cycle) multiplies every
axis velocity by r and every axis acceleration by r², so the highest rate that keeps the
axis limits is
    r_max = min(1.5, min_j sqrt(a_max_j / a_planned_j), min_j v_max_j / v_planned_j)
with a_planned, v_planned the plan's largest per-axis values (planning.measure: finite
differences of the set-points, at rest before and after). Overrides at or below 100 % are always allowed; above 100 % they are clamped
to max(1, r_max).
"""

from __future__ import annotations

import math

import numpy as np

MAX_OVERRIDE = 1.5


def max_rate(v_planned: np.ndarray, a_planned: np.ndarray, v_max: list[float | None],
             a_max: list[float | None]) -> float:
    """r_max of the module docstring (axes without a limit or without motion do not bound it)."""
    rate = MAX_OVERRIDE
    for vp, ap, vm, am in zip(v_planned, a_planned, v_max, a_max):
        if vm is not None and vp > 0:
            rate = min(rate, vm / vp)
        if am is not None and ap > 0:
            rate = min(rate, math.sqrt(am / ap))
    return float(rate)


def effective_rate(requested: float, rate_limit: float) -> float:
    """The rate actually used for an override request (fractions, 1.0 = 100 %)."""
    if requested <= 1.0:
        return requested
    return min(requested, max(1.0, rate_limit))
