"""All problems of a NURBS definition at once, each naming its field and index.

``NurbsCurve.create`` stops at the first problem; a user fixing a curve file wants every
problem in one run (Zhang's example has zero weights *and* decreasing knots). The checks
here are the same rules as ``geometry.nurbs.validate_definition`` run independently of each
other; the readers map each problem to the file line holding the offending value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.geometry import CurveError, NurbsCurve


MIN_WEIGHT, MAX_WEIGHT = 1e-6, 1e6  # beyond these the rational evaluation loses all precision
MIN_KNOT_SPAN = 1e-9  # of the knot range: shorter non-empty spans are numerically empty


@dataclass(frozen=True)
class CurveProblem:
    """One problem: ``field`` is degree | control_points | weights | knots; ``index`` the value."""

    field: str
    message: str
    index: int | None = None


def degree_problems(degree: int, n_points: int, min_degree: int, max_degree: int, name: str) -> list[CurveProblem]:
    if not min_degree <= degree <= max_degree:
        return [CurveProblem("degree", f"{name} must be between {min_degree} and {max_degree}, got {degree}")]
    if n_points < degree + 1:
        return [CurveProblem("control_points", f"a degree-{degree} curve needs at least {degree + 1} control points, got {n_points}")]
    return []


def weight_problems(weights: Sequence[float], n_points: int) -> list[CurveProblem]:
    problems = []
    if len(weights) != n_points:
        problems.append(CurveProblem("weights", f"need one weight per control point ({n_points}), got {len(weights)}"))
    for i, w in enumerate(weights):
        if not np.isfinite(w) or w <= 0:
            problems.append(CurveProblem("weights", f"weight {i + 1} is {w:g}; weights must be > 0", i))
        elif not MIN_WEIGHT <= w <= MAX_WEIGHT:
            problems.append(CurveProblem("weights", f"weight {i + 1} is {w:g}; weights must be between {MIN_WEIGHT:g} and {MAX_WEIGHT:g}", i))
    return problems


def decreasing_knot_problems(knots: Sequence[float] | np.ndarray) -> list[CurveProblem]:
    k = np.asarray(knots, dtype=float)
    return [CurveProblem("knots", f"knot {i + 1} ({k[i]:g}) is less than knot {i} ({k[i - 1]:g}); knots must not decrease", int(i))
            for i in np.flatnonzero(np.diff(k) < 0) + 1]


def knot_problems(knots: Sequence[float], n_points: int, degree: int) -> list[CurveProblem]:
    """Count, order, clamped ends, non-empty range, interior multiplicity <= degree."""
    k = np.asarray(knots, dtype=float)
    problems = []
    expected = n_points + degree + 1
    if len(k) != expected:
        problems.append(CurveProblem(
            "knots", f"need {expected} knots ({n_points} control points + degree {degree} + 1), got {len(k)}"))
    problems += decreasing_knot_problems(k)
    if len(k) < 2 * (degree + 1) or problems:
        return problems
    first, last = k[: degree + 1], k[-degree - 1:]
    if np.any(first != first[0]):
        i = int(np.flatnonzero(first != first[0])[0])
        problems.append(CurveProblem("knots", f"start not clamped: the first {degree + 1} knots must be equal", i))
    if np.any(last != last[-1]):
        i = len(k) - degree - 1 + int(np.flatnonzero(last != last[-1])[0])
        problems.append(CurveProblem("knots", f"end not clamped: the last {degree + 1} knots must be equal", i))
    if not k[-1] > k[0]:
        problems.append(CurveProblem("knots", "knot range is empty (first knot equals last knot)", len(k) - 1))
        return problems
    spans = np.diff(k)
    tiny = np.flatnonzero((spans > 0) & (spans < MIN_KNOT_SPAN * (k[-1] - k[0])))
    if len(tiny):
        i = int(tiny[0]) + 1
        problems.append(CurveProblem("knots", f"knot {i + 1} ({k[i]:.17g}) is too close to knot {i} ({k[i - 1]:.17g}): "
                                              f"make them equal or at least {MIN_KNOT_SPAN:g} of the knot range apart", i))
    # more than degree+1 equal end knots: the curve would not start (end) at the first (last)
    # control point; geometry.validate_definition does not catch this (reported)
    if k[degree + 1] == k[0]:
        problems.append(CurveProblem("knots", f"start knot {k[0]:g} repeats more than {degree + 1} (degree + 1) times", degree + 1))
    if k[-degree - 2] == k[-1]:
        problems.append(CurveProblem("knots", f"end knot {k[-1]:g} repeats more than {degree + 1} (degree + 1) times", len(k) - degree - 2))
    for i in range(degree + 1, len(k) - degree - 1 - degree):
        if k[i] == k[i + degree] and k[i] > k[0] and k[i + degree] < k[-1]:
            problems.append(CurveProblem("knots", f"interior knot {k[i]:g} repeats more than {degree} (the degree) times", i + degree))
            break
    return problems


def zero_length_problems(points: np.ndarray, tolerance_mm: float) -> list[CurveProblem]:
    if len(points) and float(np.max(np.linalg.norm(points - points[0], axis=1))) <= tolerance_mm:
        return [CurveProblem("control_points", "zero-length NURBS: all control points are the same point", len(points) - 1)]
    return []


def repeated_point_problems(points: np.ndarray, tolerance_mm: float) -> list[CurveProblem]:
    """Consecutive coincident control points: the curve's speed dx/du drops to (near) zero
    there, a cusp no feed can pass; the planners divide by |x'|."""
    if len(points) < 2:
        return []
    gaps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return [CurveProblem("control_points", f"control point {i + 2} repeats control point {i + 1}: the curve would "
                                           f"stop dead there (zero speed); remove the repeated point", int(i) + 1)
            for i in np.flatnonzero(gaps <= tolerance_mm)]


ZERO_SPEED_RATIO = 1e-6  # |x'| below this fraction of the mean parametric speed is a cusp
SPEED_SAMPLES_PER_SPAN = 64


def zero_speed_problems(curve: NurbsCurve) -> list[CurveProblem]:
    """Points of (near) zero parametric speed found on a dense sample of every knot span,
    its ends included; located at the control point with the nearest Greville abscissa.

    "Near zero" is below ZERO_SPEED_RATIO of the mean parametric speed L / (u_max - u_min).
    The arc length L is computed only when a sample is slow against the bound L <= the
    control polygon's length (positive weights: knot insertion and rational de Casteljau
    cut corners by convex combinations, so the polygons shorten towards the curve): a sample
    at or above that bound's threshold is at or above the exact one."""
    breaks = curve.breakpoints
    u = np.unique(span_samples(breaks, SPEED_SAMPLES_PER_SPAN))
    speed = np.linalg.norm(curve.derivatives(u, 1)[1], axis=1)
    u_range = curve.u_max - curve.u_min
    polygon_mm = float(np.linalg.norm(np.diff(curve.control_points, axis=0), axis=1).sum())
    if speed.min() >= ZERO_SPEED_RATIO * polygon_mm * (1.0 + 1e-9) / u_range:  # 1e-9: above the quadrature error of L
        return []
    return cusp_problems(curve, u, speed, curve.length / u_range)


def cusp_problems(curve: NurbsCurve, u: NDArray[np.float64], speed: NDArray[np.float64],
                  mean_speed: float) -> list[CurveProblem]:
    """The first sample ``u`` whose ``speed`` is below ZERO_SPEED_RATIO · ``mean_speed``, at the
    control point with the nearest Greville abscissa (none: no problem)."""
    slow = np.flatnonzero(speed < ZERO_SPEED_RATIO * mean_speed)
    if not len(slow):
        return []
    u0 = float(u[slow[0]])
    p = curve.degree
    greville = np.convolve(curve.knots[1:-1], np.ones(p) / p, mode="valid")
    index = int(np.argmin(np.abs(greville - u0)))
    return [CurveProblem("control_points", f"the curve stops dead (zero speed, a cusp) at u = {u0:g} near control "
                                           f"point {index + 1}; split the curve there", index)]


def span_samples(breaks: NDArray[np.float64], per_span: int) -> NDArray[np.float64]:
    """np.linspace(a, b, per_span + 1) for each span [a, b] of ``breaks``, concatenated (one
    vectorised expression: linspace's own formula a + (b - a) * i / n, its end exactly b)."""
    a, b = breaks[:-1, None], breaks[1:, None]
    step = (b - a) / per_span
    samples = a + np.arange(per_span + 1)[None, :] * step
    samples[:, -1] = breaks[1:]
    return samples.ravel()


def build_curve(degree: int, points: Sequence[Sequence[float] | NDArray[np.float64]], weights: Sequence[float], knots: Sequence[float],
                locate: Callable[[CurveProblem], str], *, min_degree: int = 1, max_degree: int = 9,
                degree_name: str = "degree", zero_length_mm: float = 1e-9) -> NurbsCurve:
    """Validate everything, then build the curve; raise InputErrors listing every problem.

    ``locate(problem)`` returns the ``where`` of a problem (file:line: word or field).
    """
    pts = np.asarray(points, dtype=float).reshape(len(points), -1)
    problems = degree_problems(degree, len(pts), min_degree, max_degree, degree_name)
    shape_ok = not problems  # knot rules depend on a valid degree and point count
    problems += weight_problems(weights, len(pts))
    if shape_ok:
        problems += knot_problems(knots, len(pts), degree)
    problems += zero_length_problems(pts, zero_length_mm)
    if not problems:
        problems += repeated_point_problems(pts, zero_length_mm)
    if not problems:
        try:
            curve = NurbsCurve.create(degree, pts, weights, knots)
        except CurveError as err:  # a rule checked only by the geometry: still located
            problems = [CurveProblem(err.field, err.message, err.index)]
        else:
            problems = zero_speed_problems(curve)
            if not problems:
                return curve
    raise InputErrors([InputError(locate(p), p.message) for p in problems])
