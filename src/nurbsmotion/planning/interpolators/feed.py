"""Wang's feedrate adaptation (eq. 21-28, as corrected in the reference §1), per cycle.

Chord error: a step ΔL on radius ρ has δ = ρ - sqrt(ρ² - ΔL²/4), so the largest step with
δ <= δ_max is ΔL_c = 2 sqrt(δ_max (2ρ - δ_max)) (eq. 21-22).

Resultant acceleration (eq. 24-27): sqrt(a_n² + a_t²) <= a_max. Wang takes a_t from the
previous cycle's change of feed; with that one-cycle lag the resultant overshoots a_max
wherever the curvature limit starts or stops binding. Here a_t is the change this very step
makes, and a_n is what the set-points will show at the current point: with incoming feed
V_i and outgoing feed V_{i+1} = x, the second difference of the set-points has
  a_n = (V_i² + x²) / (2ρ),  a_t = (x - V_i) / T,
and the step's feed is the largest x with a_n² + a_t² <= a_max² (a convex quartic, solved by
Newton from the right). When no x satisfies it (the point arrives too fast for the curvature)
the x that minimises the resultant is taken. The condition is symmetric in V_i and x, so the
same rule holds for the reverse interpolation.
"""

from __future__ import annotations

from math import sqrt

import numpy as np

NEWTON_ITERATIONS = 30


def chord_limited_step_mm(radius_mm: float, chord_error_mm: float) -> float:
    """ΔL_c = 2 sqrt(δ (2ρ - δ)) (Wang eq. 22); 2ρ when the tolerance exceeds the radius."""
    if radius_mm == float("inf"):
        return float("inf")
    if 2.0 * radius_mm <= chord_error_mm:
        return 2.0 * radius_mm
    return 2.0 * sqrt(chord_error_mm * (2.0 * radius_mm - chord_error_mm))


def resultant_accel_sq(v_in: float, v_out: float, radius_mm: float, period_s: float) -> float:
    a_n = (v_in * v_in + v_out * v_out) / (2.0 * radius_mm)
    a_t = (v_out - v_in) / period_s
    return a_n * a_n + a_t * a_t


def accel_limited_feed(v_in: float, cap: float, radius_mm: float, max_accel: float, period_s: float) -> float:
    """Largest outgoing feed x <= cap with resultant acceleration <= max_accel (module doc)."""
    target = max_accel * max_accel
    if resultant_accel_sq(v_in, cap, radius_mm, period_s) <= target:
        return cap
    c = 1.0 / (4.0 * radius_mm * radius_mm)  # a_n² = c (V² + x²)²
    inv_t2 = 1.0 / (period_s * period_s)
    x = cap
    for _ in range(NEWTON_ITERATIONS):
        s = v_in * v_in + x * x
        g = c * s * s + (x - v_in) * (x - v_in) * inv_t2 - target
        slope = 4.0 * c * s * x + 2.0 * (x - v_in) * inv_t2
        if slope <= 0.0:
            break  # passed the minimum: no feasible feed
        step = g / slope
        x -= step
        if step <= 1e-12 * (abs(x) + 1e-9):
            return max(x, 0.0)
    # no root: the feed with the smallest resultant (Newton on the slope)
    x = min(max(x, 0.0), v_in)
    for _ in range(NEWTON_ITERATIONS):
        s = v_in * v_in + x * x
        slope = 4.0 * c * s * x + 2.0 * (x - v_in) * inv_t2
        curvature = 4.0 * c * (v_in * v_in + 3.0 * x * x) + 2.0 * inv_t2
        step = slope / curvature
        x -= step
        if abs(step) <= 1e-12 * (abs(x) + 1e-9):
            break
    return min(max(x, 0.0), cap)


class FeedLimits:
    """The adaptive feed cap of one cycle: min(V, ΔL_c / T, accel-limited feed) (Wang eq. 28)."""

    def __init__(self, period_s: float, chord_error_mm: float, max_accel_mm_s2: float, adaptive: bool):
        self.period_s = period_s
        self.chord_error_mm = chord_error_mm
        self.max_accel = max_accel_mm_s2
        self.adaptive = adaptive

    def cap(self, radius_mm: float, tangential_mm_s2: float) -> float:
        """The static feed cap at radius ρ while accelerating at a_t along the path:
        min(ΔL_c / T, sqrt(ρ sqrt(a_max² - a_t²))) (Wang eq. 22 and 25 solved for V)."""
        if not self.adaptive or radius_mm == float("inf"):
            return float("inf")
        normal = sqrt(max(self.max_accel * self.max_accel - tangential_mm_s2 * tangential_mm_s2, 0.0))
        return min(chord_limited_step_mm(radius_mm, self.chord_error_mm) / self.period_s, sqrt(radius_mm * normal))

    def caps(self, radius_mm: np.ndarray, tangential_mm_s2: float) -> np.ndarray:
        """``cap`` for an array of radii (numpy)."""
        if not self.adaptive:
            return np.full(len(radius_mm), np.inf)
        r = np.asarray(radius_mm, dtype=float)
        d = self.chord_error_mm
        with np.errstate(invalid="ignore", over="ignore"):
            chord = np.where(2.0 * r <= d, 2.0 * r, 2.0 * np.sqrt(d * np.maximum(2.0 * r - d, 0.0)))
            normal = np.sqrt(max(self.max_accel**2 - tangential_mm_s2**2, 0.0))
            cap = np.minimum(chord / self.period_s, np.sqrt(r * normal))
        return np.where(np.isinf(r), np.inf, cap)

    def feed_as_printed(self, wanted_mm_s: float, radius_mm: float, a_t_before: float) -> float:
        """Wang eq. 21-28 as printed: ΔL = min(V T, ΔL_c, ΔL_a) with ρ at the current point and
        δ_a = T²/8 sqrt(a_max² - a_t²), a_t the change of feed in the previous cycle."""
        if not self.adaptive or radius_mm == float("inf"):
            return wanted_mm_s
        delta_a = self.period_s**2 / 8.0 * sqrt(max(self.max_accel**2 - a_t_before**2, 0.0))
        step_c = chord_limited_step_mm(radius_mm, self.chord_error_mm)
        step_a = chord_limited_step_mm(radius_mm, delta_a) if delta_a > 0.0 else 0.0
        return min(wanted_mm_s, step_c / self.period_s, step_a / self.period_s)

    def feed(self, wanted_mm_s: float, v_in_mm_s: float, radius_mm: float) -> float:
        """The outgoing feed of this cycle: wanted, capped by eq. 22 and the resultant rule."""
        if not self.adaptive:
            return wanted_mm_s
        if radius_mm == float("inf"):
            return min(wanted_mm_s, v_in_mm_s + self.max_accel * self.period_s)
        d = self.chord_error_mm
        chord_step = 2.0 * radius_mm if 2.0 * radius_mm <= d else 2.0 * sqrt(d * (2.0 * radius_mm - d))
        cap = min(wanted_mm_s, chord_step / self.period_s)
        a_n = (v_in_mm_s * v_in_mm_s + cap * cap) / (2.0 * radius_mm)
        a_t = (cap - v_in_mm_s) / self.period_s
        if a_n * a_n + a_t * a_t <= self.max_accel * self.max_accel:
            return cap
        return accel_limited_feed(v_in_mm_s, cap, radius_mm, self.max_accel, self.period_s)


def accel_limited_feed_straight(v_in: float, cap: float, max_accel: float, period_s: float) -> float:
    """On a straight piece only the tangential change counts: x <= v_in + a_max T."""
    return min(cap, v_in + max_accel * period_s)
