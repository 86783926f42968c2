"""One interpolation step along a chain of curves: Taylor predictor, Zhang's chord correction.

Everything here is scalar Python on tuples (NurbsCurve.point_and_derivatives): a per-cycle
numpy call costs microseconds, more than the arithmetic it would save. Positions are XYZ.

Taylor predictors (reference §1, with V and A taken from the planned step lengths, so that
V T + A T^2 / 2 equals the wanted step ΔL):
  first order  u_{i+1} = u_i + ΔL / |x'|
  second order u_{i+1} = u_i + ΔL / |x'| - (V T)^2 (x'·x'') / (2 |x'|^4),
               V T = (ΔL_i + ΔL_{i+1}) / 2 (the feed at t_i), A T^2 / 2 = (ΔL_{i+1} - ΔL_i) / 2.
Zhang's modification: after the predictor, correct u_{i+1} so that the chord
|x(u_{i+1}) - x(u_i)| equals ΔL (Newton on the chord length, kept inside a bracket and
bisected when a Newton step leaves it: plain Newton diverges at sharp corners with T = 4 ms),
then estimate the step's chord error by the midpoint rule (Zhang eq. 12)
δ ≈ |(x(u_i) + x(u_{i+1}))/2 - x((u_i + u_{i+1})/2)| and, when δ > δ_max, shorten the step by
sqrt(δ_max / δ) (Zhang eq. 15) and correct again.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import sqrt
from typing import Callable, Sequence

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.planning.interpolators.fastcurve import scalar_evaluators

Vec = tuple[float, ...]
CHORD_TOLERANCE_MM = 1e-10  # Zhang correction: |chord - ΔL| below this is exact
MAX_CORRECTION_ITERATIONS = 40
MAX_SHORTENINGS = 3  # Zhang eq. 15 re-tries per cycle


def distance(a: Vec, b: Vec) -> float:
    dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return sqrt(dx * dx + dy * dy + dz * dz)


def radius_of_curvature(d1: Vec, d2: Vec) -> float:
    """ρ = |x'|^3 / |x' × x''| (reference §1; Wang eq. 23 corrected); inf on straight pieces."""
    s2 = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    cx = d1[1] * d2[2] - d1[2] * d2[1]
    cy = d1[2] * d2[0] - d1[0] * d2[2]
    cz = d1[0] * d2[1] - d1[1] * d2[0]
    cross = sqrt(cx * cx + cy * cy + cz * cz)
    return s2 * sqrt(s2) / cross if cross > 1e-300 else float("inf")


@dataclass(slots=True)
class PathPoint:
    """A place on a CurvePath: curve index j, parameter u, position x and x', x'' there."""

    j: int
    u: float
    x: Vec
    d1: Vec
    d2: Vec


class CurvePath:
    """Curves traversed one after the other (a run of blocks between stops, or its reverse).

    ``curves`` may be lazy: a callable giving curve j, with ``u_ranges`` [(u_min, u_max)];
    a curve's scalar evaluators are built the first time the path reaches it (a reversed
    run is only visited near its stop, a long G-code run has thousands of blocks).
    """

    def __init__(self, curves: Sequence[NurbsCurve] | Callable[[int], NurbsCurve],
                 u_ranges: Sequence[tuple[float, float]] | None = None):
        if callable(curves):
            if u_ranges is None:
                raise ValueError("a lazy CurvePath needs the u range of every curve")
            self.curve_at = curves
        else:
            listed = list(curves)
            self.curve_at = listed.__getitem__
            u_ranges = [(c.u_min, c.u_max) for c in listed]
        self.u_min = [float(a) for a, _ in u_ranges]
        self.u_max = [float(b) for _, b in u_ranges]
        self.last = len(self.u_min) - 1
        self.evaluate: list[Callable[[float], tuple[Vec, Vec, Vec]]] = [self._loader(j, 0) for j in range(self.last + 1)]
        self.point: list[Callable[[float], Vec]] = [self._loader(j, 1) for j in range(self.last + 1)]

    def _loader(self, j: int, which: int) -> Callable:
        def load(u: float):
            self.evaluate[j], self.point[j] = scalar_evaluators(self.curve_at(j))
            return (self.evaluate[j], self.point[j])[which](u)
        return load

    def at(self, j: int, u: float) -> PathPoint:
        x, d1, d2 = self.evaluate[j](u)
        return PathPoint(j, u, x, d1, d2)

    def start(self) -> PathPoint:
        return self.at(0, self.u_min[0])

    def end(self) -> PathPoint:
        return self.at(self.last, self.u_max[self.last])


def taylor_du(d1: Vec, d2: Vec, step_mm: float, vt_mm: float, order: int) -> float:
    """Parameter increment of the Taylor predictor for a step of step_mm (see module doc)."""
    s2 = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    du = step_mm / sqrt(s2)
    if order >= 2:
        dot = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
        du -= vt_mm * vt_mm * dot / (2.0 * s2 * s2)
    return du


def predict(path: CurvePath, here: PathPoint, step_mm: float, vt_mm: float, order: int) -> tuple[PathPoint, bool]:
    """Taylor step of step_mm from ``here``; a step past the end of a curve carries its leftover
    (step minus the chord to that curve's end) into the next curve. Returns (point, reached_end)."""
    p = here
    remaining, vt = step_mm, vt_mm
    while True:
        u_new = p.u + taylor_du(p.d1, p.d2, remaining, vt, order)
        if u_new < path.u_max[p.j]:
            if u_new <= p.u:  # the second-order term can only shorten, never reverse, a step
                u_new = p.u + taylor_du(p.d1, p.d2, remaining, 0.0, 1)
            return path.at(p.j, u_new), False
        end = path.at(p.j, path.u_max[p.j])
        if p.j == path.last:
            return end, True
        leftover = remaining - distance(end.x, p.x)
        if leftover <= 0.0:
            return end, False
        scale = leftover / remaining
        remaining, vt = leftover, vt * scale
        p = path.at(p.j + 1, path.u_min[p.j + 1])


def solve_chord(path: CurvePath, anchor: Vec, length_mm: float, guess: PathPoint, lower_u: float | None,
                tolerance_mm: float = CHORD_TOLERANCE_MM) -> tuple[PathPoint, bool]:
    """The point after ``anchor`` at chord distance length_mm, starting from ``guess``.

    Newton on h(u) = |x(u) - anchor| - length with h' = (x - anchor)·x' / |x - anchor|,
    inside the bracket [lower_u (h < 0), u_max of the curve]; a step leaving the bracket is
    replaced by bisection. If the curve's end is still too close, the search moves on to the
    next curve; at the end of the path returns (end, True).
    """
    p = guess
    j = p.j
    lo = path.u_min[j] if lower_u is None else lower_u
    hi = path.u_max[j]
    hi_known = False
    for _ in range(MAX_CORRECTION_ITERATIONS):
        x, d1 = p.x, p.d1
        rx, ry, rz = x[0] - anchor[0], x[1] - anchor[1], x[2] - anchor[2]
        chord = sqrt(rx * rx + ry * ry + rz * rz)
        h = chord - length_mm
        if -tolerance_mm <= h <= tolerance_mm:
            return p, False
        if h < 0.0:
            lo = p.u
            if p.u >= path.u_max[j]:  # the whole curve is too close: continue on the next one
                if j == path.last:
                    return p, True
                j += 1
                lo, hi, hi_known = path.u_min[j], path.u_max[j], False
                p = path.at(j, lo)
                continue
        else:
            hi, hi_known = p.u, True
        slope = (rx * d1[0] + ry * d1[1] + rz * d1[2]) / chord if chord > 0.0 else 0.0
        u_next = p.u - h / slope if slope > 0.0 else hi
        if not lo < u_next < hi:
            u_next = hi if (not hi_known and h < 0.0) else 0.5 * (lo + hi)
        p = path.at(j, u_next)
    return p, False


def midpoint_chord_error(path: CurvePath, a: PathPoint, b: PathPoint) -> float:
    """Zhang eq. 12: |(x(u_a) + x(u_b))/2 - x((u_a + u_b)/2)| (0 across a curve junction)."""
    if a.j != b.j:
        return 0.0
    m = path.point[a.j](0.5 * (a.u + b.u))
    return distance(((a.x[0] + b.x[0]) * 0.5, (a.x[1] + b.x[1]) * 0.5, (a.x[2] + b.x[2]) * 0.5), m)


@dataclass(frozen=True)
class Stepper:
    """How a method turns a wanted step length into the next point."""

    order: int  # Taylor order of the predictor (1 or 2)
    correct: bool  # Zhang: correct u so the chord equals the step, midpoint chord-error check
    chord_error_mm: float = 0.01

    def step(self, path: CurvePath, here: PathPoint, step_mm: float, previous_step_mm: float) -> tuple[PathPoint, float, bool]:
        """Advance by step_mm; returns (point, step actually planned in mm, reached_end)."""
        vt = 0.5 * (previous_step_mm + step_mm)
        guess, at_end = predict(path, here, step_mm, vt, self.order)
        if not self.correct:
            return guess, step_mm, at_end
        lower = here.u if guess.j == here.j else None
        for _ in range(MAX_SHORTENINGS + 1):
            point, at_end = solve_chord(path, here.x, step_mm, guess, lower)
            if at_end:
                return point, step_mm, True
            delta = midpoint_chord_error(path, here, point)
            if delta <= self.chord_error_mm:
                break
            step_mm *= sqrt(self.chord_error_mm / delta) * 0.999
            guess = path.at(here.j, here.u + taylor_du(here.d1, here.d2, step_mm, 0.0, 1)) if point.j == here.j else point
            if guess.u >= path.u_max[guess.j]:
                guess = path.at(guess.j, 0.5 * (here.u + path.u_max[guess.j])) if guess.j == here.j else guess
        return point, step_mm, False
