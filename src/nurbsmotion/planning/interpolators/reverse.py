"""Reverse interpolation (Wang eq. 18-20): where to start decelerating so the stop is exact.

The run's curves are reversed (NurbsCurve.reversed(): w_r,i = w_{n-i}, P_r,i = P_{n-i},
u_r,i = (u_first + u_last) - u_{n+p+1-i}) and interpolated from the stop point, from rest,
with the linear acc/dec a_l (and the same feed adaptation as the forward pass), until the
feed reaches the highest feed of the run. That gives a table of reverse set-points q_k
(q_0 = the stop) with the chord L_k of reverse step k (q_{k-1} -> q_k), its feed
V_k = L_k / T and the discrete remaining length Λ_k = L_1 + ... + L_k.

V_achieve at a point with remaining length S in [Λ_k, Λ_{k+1}] is V_k + f (V_{k+1} - V_k)
with f = (S - Λ_k) / L_{k+1}. Because L_k = V_k T, one forward step at V_achieve leaves
S' = Λ_{k-1} + f L_k: the same fraction f one table step closer. So once the forward pass
follows the table (Wang: from the cycle where V_achieve <= V_next), its steps are
(k+f) ... (1+f) table steps long, then a last step of f L_1 <= a_l T² that lands exactly on
the stop point with the feed reaching zero in that same cycle: no tail, no stop from speed.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass, field
from math import inf

from nurbsmotion.planning.interpolators.feed import FeedLimits
from nurbsmotion.planning.interpolators.stepping import (
    CurvePath,
    PathPoint,
    Stepper,
    Vec,
    distance,
    radius_of_curvature,
    solve_chord,
)


@dataclass
class ReverseTable:
    """Reverse set-points from the stop backwards, in reverse-path coordinates."""

    path: CurvePath  # the reversed run
    j: list[int] = field(default_factory=list)  # reverse curve index of q_k
    u: list[float] = field(default_factory=list)  # reverse parameter of q_k
    x: list[Vec] = field(default_factory=list)
    step_mm: list[float] = field(default_factory=list)  # L_k (L_0 = 0)
    remaining_mm: list[float] = field(default_factory=list)  # Λ_k
    feed_mm_s: list[float] = field(default_factory=list)  # V_k = L_k / T (V_0 = 0)
    complete: bool = False  # True when the table reaches back to the start of the run

    def __len__(self) -> int:
        return len(self.u)

    def v_achieve(self, remaining_mm: float) -> float:
        """V_achieve for a remaining length (inf beyond the table), linear between entries."""
        k = self.interval(remaining_mm)
        if k is None:
            return inf
        f = min((remaining_mm - self.remaining_mm[k]) / self.step_mm[k + 1], 1.0)
        return self.feed_mm_s[k] + f * (self.feed_mm_s[k + 1] - self.feed_mm_s[k])

    def interval(self, remaining_mm: float) -> int | None:
        """k with Λ_k <= S < Λ_{k+1}; past the table None, or the last interval of a complete table."""
        lam = self.remaining_mm
        if len(lam) < 2:
            return None
        if remaining_mm >= lam[-1]:
            return len(lam) - 2 if self.complete else None
        return max(bisect_right(lam, remaining_mm) - 1, 0)

    def point_at(self, remaining_mm: float) -> PathPoint:
        """The point (reverse-path coordinates) at remaining length S on the table's path."""
        k = self.interval(remaining_mm)
        if k is None:
            k = len(self.u) - 2
        if remaining_mm <= self.remaining_mm[k] + 1e-13 * (1.0 + self.remaining_mm[k]):
            return self.path.at(self.j[k], self.u[k])
        target = remaining_mm - self.remaining_mm[k]
        if target >= self.step_mm[k + 1]:
            return self.path.at(self.j[k + 1], self.u[k + 1])
        start = self.path.at(self.j[k], self.u[k])
        frac = target / self.step_mm[k + 1]
        if self.j[k + 1] == self.j[k]:
            guess = self.path.at(self.j[k], self.u[k] + frac * (self.u[k + 1] - self.u[k]))
        else:
            guess = start
        point, _ = solve_chord(self.path, start.x, target, guess, self.u[k])
        return point


def build_reverse_table(reversed_path: CurvePath, feeds_mm_s: list[float], accel_mm_s2: float,
                        limits: FeedLimits, stepper: Stepper, period_s: float) -> ReverseTable:
    """Interpolate the reversed run from rest at the linear acc/dec a_l (Wang eq. 19-20).

    Builds the final ramp only: it stops where the feed reaches the run's highest feed or
    where a cap (the curve's feed, the adaptive limits at either end of the step) would cut
    the ramp; beyond that the slow-down profile (slowdown.py) gives the cap.
    ``feeds_mm_s``: the feed of each reversed curve.
    """
    table = ReverseTable(reversed_path)
    here = reversed_path.start()
    table.j.append(here.j)
    table.u.append(here.u)
    table.x.append(here.x)
    table.step_mm.append(0.0)
    table.remaining_mm.append(0.0)
    table.feed_mm_s.append(0.0)
    v, previous_step = 0.0, 0.0
    ramp = accel_mm_s2 * period_s
    top = max(feeds_mm_s)
    while v < top:
        v_step = v + ramp
        if v_step > min(feeds_mm_s[here.j], limits.cap(radius_of_curvature(here.d1, here.d2), accel_mm_s2)):
            break
        point, planned, at_end = stepper.step(reversed_path, here, v_step * period_s, previous_step)
        if not at_end and v_step > limits.cap(radius_of_curvature(point.d1, point.d2), accel_mm_s2):
            break
        chord = distance(point.x, here.x)
        if chord <= 0.0:
            table.complete = True
            break
        table.j.append(point.j)
        table.u.append(point.u)
        table.x.append(point.x)
        table.step_mm.append(chord)
        table.remaining_mm.append(table.remaining_mm[-1] + chord)
        # V_k = L_k / T exactly (this keeps the phase, see the module doc); the last, clamped
        # step that reaches the run's start keeps the feed it was planned with
        table.feed_mm_s.append(v_step if at_end else chord / period_s)
        if at_end:
            table.complete = True
            break
        here, previous_step, v = point, planned, chord / period_s
    return table
