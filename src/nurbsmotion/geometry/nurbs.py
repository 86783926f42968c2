"""Non-uniform rational B-spline curves: validation, de Boor evaluation, derivatives.

A NURBS curve of degree p with control points P_i and weights w_i on the clamped knot
vector U (length n+p+2) is x(u) = C(u)/W(u) with the homogeneous B-spline
A(u) = [C, W] = sum_i N_{i,p}(u) [w_i P_i, w_i].

Derivatives of A are B-splines of degree p-k on U[k:-k] whose control points are the
k-th differences of the homogeneous control points (Piegl & Tiller eq. 3.8):
Q^(k)_i = (p-k+1) (Q^(k-1)_{i+1} - Q^(k-1)_i) / (u_{i+p+1} - u_{i+k}).
De Boor's algorithm evaluates them once per knot span at its left knot u_s: on a span A is a
polynomial of degree p, so A(u) = sum_k A^(k)(u_s) (u - u_s)^k / k! exactly, and every
evaluation after that is Horner's scheme on these Taylor coefficients (value and derivatives
together). The rational derivatives follow from the quotient rule (reference §1):
  x'   = (C'   - W' x) / W
  x''  = (C''  - 2 W' x' - W'' x) / W
  x''' = (C''' - 3 W' x'' - 3 W'' x' - W''' x) / W
The speed |x'|, the arc length and its inverse are arc_length.py's, from the same Taylor
coefficients.
"""

from __future__ import annotations

import bisect
import functools
from dataclasses import dataclass
from functools import cached_property
from math import comb
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.geometry.arc_length import ArcLength

MAX_DEGREE = 9
MAX_DIM = 6
KNOT_TOLERANCE = 1e-12
MIN_WEIGHT, MAX_WEIGHT = 1e-9, 1e9  # beyond this the homogeneous form under/overflows


class CurveError(ValueError):
    """An invalid curve definition; ``field`` names what is wrong (degree, knots, ...).

    ``index`` is the position of the offending value within that field, when there is one.
    """

    def __init__(self, field: str, message: str, index: int | None = None) -> None:
        self.field = field
        self.index = index
        self.message = message
        super().__init__(f"{field}: {message}")


def _as_float_array(values: ArrayLike, field: str, ndim: int) -> NDArray[np.float64]:
    try:
        array = np.array(values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise CurveError(field, f"must be numbers ({err})") from None
    if array.ndim != ndim:
        shape = "a list of numbers" if ndim == 1 else "a list of points of equal dimension"
        raise CurveError(field, f"must be {shape}")
    bad = np.flatnonzero(~np.isfinite(array).reshape(len(array), -1).all(axis=1)) if len(array) else np.empty(0, np.intp)
    if len(bad):
        raise CurveError(field, f"value {int(bad[0]) + 1} is not a finite number", int(bad[0]))
    return array


def clamped_uniform_knots(n_points: int, degree: int, u_min: float = 0.0, u_max: float = 1.0) -> NDArray[np.float64]:
    """Clamped knot vector with evenly spaced interior knots (length n_points + degree + 1)."""
    interior = np.linspace(u_min, u_max, n_points - degree + 1)
    return np.concatenate([np.full(degree, u_min), interior, np.full(degree, u_max)])


def validate_definition(degree: int, points: NDArray[np.float64], weights: NDArray[np.float64],
                        knots: NDArray[np.float64]) -> None:
    """Raise CurveError for the first problem of a curve definition, naming the field."""
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)):
        raise CurveError("degree", f"must be an integer, got {degree!r}")
    if not 1 <= degree <= MAX_DEGREE:
        raise CurveError("degree", f"must be between 1 and {MAX_DEGREE}, got {degree}")
    n_points = len(points)
    if n_points < degree + 1:
        raise CurveError("control_points", f"a degree-{degree} curve needs at least {degree + 1} control points, got {n_points}")
    if not 1 <= points.shape[1] <= MAX_DIM:
        raise CurveError("control_points", f"points must have 1 to {MAX_DIM} coordinates, got {points.shape[1]}")
    if len(weights) != n_points:
        raise CurveError("weights", f"need one weight per control point ({n_points}), got {len(weights)}")
    nonpositive = np.flatnonzero(weights <= 0)
    if len(nonpositive):
        i = int(nonpositive[0])
        raise CurveError("weights", f"weight {i + 1} is {weights[i]:g}; weights must be > 0", i)
    out_of_range = np.flatnonzero((weights < MIN_WEIGHT) | (weights > MAX_WEIGHT))
    if len(out_of_range):
        i = int(out_of_range[0])
        raise CurveError("weights", f"weight {i + 1} is {weights[i]:g}; weights must lie in [{MIN_WEIGHT:g}, {MAX_WEIGHT:g}]", i)
    expected = n_points + degree + 1
    if len(knots) != expected:
        raise CurveError("knots", f"need {expected} knots ({n_points} control points + degree {degree} + 1), got {len(knots)}")
    decreasing = np.flatnonzero(np.diff(knots) < 0)
    if len(decreasing):
        i = int(decreasing[0]) + 1
        raise CurveError("knots", f"knot {i + 1} ({knots[i]:g}) is less than knot {i} ({knots[i - 1]:g}); knots must not decrease", i)
    if np.any(knots[: degree + 1] != knots[0]) or np.any(knots[-degree - 1:] != knots[-1]):
        raise CurveError("knots", f"ends must be clamped: the first and last {degree + 1} knots must be equal")
    if not knots[-1] - knots[0] > KNOT_TOLERANCE:
        raise CurveError("knots", "knot range is empty (first knot equals last knot)")
    interior = knots[degree + 1: -degree - 1]
    at_ends = np.flatnonzero((interior == knots[0]) | (interior == knots[-1]))
    if len(at_ends):
        i = int(at_ends[0]) + degree + 1
        raise CurveError("knots", f"knot {i + 1} ({knots[i]:g}) repeats an end knot: each end holds exactly "
                         f"{degree + 1} equal knots (degree + 1)", i)
    if len(interior):
        values, counts = np.unique(interior, return_counts=True)
        too_many = np.flatnonzero(counts > degree)
        if len(too_many):
            v = values[too_many[0]]
            raise CurveError("knots", f"interior knot {v:g} repeats {counts[too_many[0]]} times; at most {degree} (the degree) are allowed")


def _derivative_control_points(degree: int, homogeneous: NDArray[np.float64], knots: NDArray[np.float64],
                               order: int) -> list[NDArray[np.float64]]:
    """Control points of A, A', ..., A^(order) (Piegl & Tiller eq. 3.8); empty arrays past the degree."""
    result = [homogeneous]
    q = homogeneous
    for k in range(1, order + 1):
        if k > degree:
            result.append(np.zeros((0, homogeneous.shape[1])))
            continue
        p = degree - k + 1
        span = knots[p + k: p + k + len(q) - 1] - knots[k: k + len(q) - 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(span > 0, p / np.where(span > 0, span, 1.0), 0.0)
        q = (q[1:] - q[:-1]) * factor[:, None]
        result.append(q)
    return result


def de_boor(q: NDArray[np.float64], knots: NDArray[np.float64], degree: int, spans: NDArray[np.intp],
            u: NDArray[np.float64]) -> NDArray[np.float64]:
    """De Boor's algorithm, vectorised over u: sum_i N_{i,degree}(u) q_i.

    ``spans`` are indices k into ``knots`` with knots[k] <= u < knots[k+1] (k >= degree).
    Returns a coordinate-major array (q.shape[1], len(u)):
    d_j <- d_{j-1} + alpha (d_j - d_{j-1}), alpha = (u - u_{k-p+j}) / (u_{k+1+j-r} - u_{k-p+j}).
    """
    qt = np.ascontiguousarray(q.T)
    d = [qt.take(spans + (j - degree), axis=1) for j in range(degree + 1)]
    for r in range(1, degree + 1):
        for j in range(degree, r - 1, -1):
            left = knots.take(spans + (j - degree))
            denom = knots.take(spans + (j + 1 - r)) - left
            alpha = (u - left) / np.where(denom > 0, denom, np.inf)
            d[j] = d[j - 1] + alpha * (d[j] - d[j - 1])
    return d[degree]


def rational_derivatives(homogeneous_derivs: Sequence[NDArray[np.float64]]) -> list[NDArray[np.float64]]:
    """x and its derivatives from the derivatives of A = [C, W], coordinate-major (dim+1, m).

    General Leibniz form of the reference formulas:
    x^(k) = (C^(k) - sum_{i=1..k} binom(k, i) W^(i) x^(k-i)) / W
    """
    inv_w = 1.0 / homogeneous_derivs[0][-1]
    out: list[NDArray[np.float64]] = []
    for k, a_k in enumerate(homogeneous_derivs):
        numerator = a_k[:-1]
        for i in range(1, k + 1):
            w_i = homogeneous_derivs[i][-1]
            if not w_i.any():  # W^(i) = 0 (past the degree, or a polynomial curve): the term is 0
                continue
            numerator = numerator - comb(k, i) * w_i * out[k - i]
        out.append(numerator * inv_w)
    return out


# points per block of work: keeps the arrays in the CPU cache and the gathered Taylor
# coefficients ((p+1) x (dim+1) x chunk doubles) under glibc's 128 KiB mmap threshold for
# p = 2 in 3-D (4096 points: 2x slower with the default allocator, measured)
EVALUATION_CHUNK = 2048


@functools.lru_cache(maxsize=16)
def _bernstein_to_power(p: int) -> NDArray[np.float64]:
    """M[k, i] = (-1)^(k-i) C(p, k) C(k, i) (i <= k): the degree-p Bernstein basis in powers of t."""
    out = np.zeros((p + 1, p + 1))
    for k in range(p + 1):
        for i in range(k + 1):
            out[k, i] = (-1.0) ** (k - i) * comb(p, k) * comb(k, i)
    out.setflags(write=False)
    return out


def bezier_taylor(homogeneous: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Taylor coefficients (p+1, dim+1, 1) at the start of a one-span curve (a Bezier of width
    ``width`` in u): c_k = width^-k sum_i M[k, i] H_i (_bernstein_to_power): de Boor's result
    without its per-order passes."""
    p = len(homogeneous) - 1
    scale = width ** -np.arange(p + 1.0)
    return np.ascontiguousarray(((_bernstein_to_power(p) @ homogeneous) * scale[:, None])[:, :, None])


@dataclass(frozen=True, eq=False)
class NurbsCurve:
    """An immutable, validated NURBS curve. Construct it through ``NurbsCurve.create``.

    Evaluation: ``derivatives(u, order)`` (vectorised), ``point_and_derivatives(u)``
    (fast scalar path for per-cycle use), ``curvature``, ``arc_length``,
    ``u_at_arc_length``; ``reversed()`` gives the same path traced backwards.
    """

    degree: int
    control_points: NDArray[np.float64]
    weights: NDArray[np.float64]
    knots: NDArray[np.float64]

    @classmethod
    def create(cls, degree: int, control_points: ArrayLike, weights: ArrayLike | None = None,
               knots: ArrayLike | None = None) -> "NurbsCurve":
        """Validate and build a curve; weights default to 1, knots to clamped uniform on [0, 1]."""
        points = _as_float_array(control_points, "control_points", 2)
        if points.ndim != 2 or len(points) == 0:
            raise CurveError("control_points", "need at least one point")
        if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)):
            raise CurveError("degree", f"must be an integer, got {degree!r}")
        w = np.ones(len(points)) if weights is None else _as_float_array(weights, "weights", 1)
        if knots is None:
            if not 1 <= degree < len(points):
                validate_definition(int(degree), points, w, np.zeros(len(points) + int(degree) + 1))
            k = clamped_uniform_knots(len(points), int(degree))
        else:
            k = _as_float_array(knots, "knots", 1)
        validate_definition(int(degree), points, w, k)
        for array in (points, w, k):
            array.setflags(write=False)
        return cls(int(degree), points, w, k)

    # ---- basic properties -------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.control_points.shape[1])

    @property
    def u_min(self) -> float:
        return float(self.knots[0])

    @property
    def u_max(self) -> float:
        return float(self.knots[-1])

    @property
    def start_point(self) -> NDArray[np.float64]:
        return self.control_points[0].copy()

    @property
    def end_point(self) -> NDArray[np.float64]:
        return self.control_points[-1].copy()

    @cached_property
    def homogeneous(self) -> NDArray[np.float64]:
        """Control points in homogeneous form [w P, w], shape (n+1, dim+1)."""
        return np.hstack([self.control_points * self.weights[:, None], self.weights[:, None]])

    @cached_property
    def _derivative_points(self) -> list[NDArray[np.float64]]:
        return _derivative_control_points(self.degree, self.homogeneous, self.knots, self.degree)

    @cached_property
    def breakpoints(self) -> NDArray[np.float64]:
        """Distinct knot values: the ends of the non-empty knot spans."""
        return np.unique(self.knots)

    # ---- vectorised evaluation ------------------------------------------------------------
    @cached_property
    def _taylor_coefficients(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(lefts, c): the left knot of every non-empty span and c[k, :, i] = A^(k)(lefts[i]) / k!,
        shape (p+1, dim+1, spans), from de Boor on the derivative control points."""
        lefts = self.breakpoints[:-1]
        if len(lefts) == 1 and self.degree >= 3:
            return lefts, bezier_taylor(self.homogeneous, float(self.breakpoints[1] - lefts[0]))
        spans = np.searchsorted(self.knots, lefts, side="right") - 1
        points = self._derivative_points
        coeffs = []
        factorial = 1.0
        for k in range(self.degree + 1):
            factorial *= max(k, 1)
            knots_k = self.knots[k: len(self.knots) - k] if k else self.knots
            coeffs.append(de_boor(points[k], knots_k, self.degree - k, spans - k, lefts) / factorial)
        return lefts, np.ascontiguousarray(np.stack(coeffs))

    def homogeneous_derivatives(self, u: NDArray[np.float64], order: int = 0) -> list[NDArray[np.float64]]:
        """A, A', ... up to A^(order) at each u, each a coordinate-major array (dim+1, len(u)):
        Horner's scheme on the span's Taylor coefficients, d_k <- d_k t + k d_(k-1)."""
        lefts, coeffs = self._taylor_coefficients
        i = np.clip(np.searchsorted(lefts, u, side="right") - 1, 0, len(lefts) - 1)
        t = u - lefts.take(i)
        g = coeffs.take(i, axis=2)
        p = self.degree
        d: list = [g[p]] + [None] * order
        for j in range(p - 1, -1, -1):
            for k in range(min(order, p - j), 0, -1):
                # d_k starts at 0: its first step is k d_(k-1) (0 t + k d = k d exactly)
                d[k] = (k * d[k - 1] if k > 1 else d[k - 1]) if d[k] is None else d[k] * t + k * d[k - 1]
            d[0] = d[0] * t + g[j]
        return [dk if dk is not None else np.zeros((self.dim + 1, len(u))) for dk in d]

    def derivatives_by_coordinate(self, u: NDArray[np.float64], order: int) -> list[NDArray[np.float64]]:
        """x, x', ... up to x^(order) at each u of a 1-D array, each coordinate-major
        (dim, len(u)): ``derivatives`` without its transposes, for callers that compute on
        whole coordinate rows (the planner's path grid)."""
        if not 0 <= order <= 3:
            raise ValueError("derivative order must be 0..3")
        uu = np.asarray(u, dtype=np.float64)
        if len(uu) <= EVALUATION_CHUNK:
            return rational_derivatives(self.homogeneous_derivatives(uu, order))
        out = [np.empty((self.dim, len(uu))) for _ in range(order + 1)]
        for start in range(0, len(uu), EVALUATION_CHUNK):
            chunk = uu[start: start + EVALUATION_CHUNK]
            for k, x_k in enumerate(rational_derivatives(self.homogeneous_derivatives(chunk, order))):
                out[k][:, start: start + len(chunk)] = x_k
        return out

    def derivatives(self, u: ArrayLike, order: int = 2) -> NDArray[np.float64]:
        """x and its derivatives up to ``order`` at u: array (order+1, len(u), dim); (order+1, dim) for scalar u.

        Works through u in cache-sized chunks; each chunk is de Boor on the derivative
        control points, then the rational quotient rule.
        """
        if not 0 <= order <= 3:
            raise ValueError("derivative order must be 0..3")
        uu = np.atleast_1d(np.asarray(u, dtype=np.float64))
        out = np.empty((order + 1, len(uu), self.dim))
        for start in range(0, len(uu), EVALUATION_CHUNK):
            chunk = uu[start: start + EVALUATION_CHUNK]
            for k, x_k in enumerate(rational_derivatives(self.homogeneous_derivatives(chunk, order))):
                out[k, start: start + len(chunk)] = x_k.T
        return out[:, 0] if np.ndim(u) == 0 else out

    def points(self, u: ArrayLike) -> NDArray[np.float64]:
        """x(u) for an array of u: (len(u), dim); (dim,) for scalar u."""
        return self.derivatives(u, 0)[0]

    def curvature(self, u: ArrayLike) -> NDArray[np.float64] | float:
        """kappa = |x' x x''| / |x'|^3, written with the Gram determinant so it holds in any dimension."""
        _, d1, d2 = self.derivatives(u, 2)
        speed2 = np.einsum("...i,...i->...", d1, d1)
        cross2 = speed2 * np.einsum("...i,...i->...", d2, d2) - np.einsum("...i,...i->...", d1, d2) ** 2
        kappa = np.sqrt(np.maximum(cross2, 0.0)) / np.maximum(speed2, 1e-300) ** 1.5
        return float(kappa) if np.ndim(u) == 0 else kappa

    # ---- fast scalar path -----------------------------------------------------------------
    @cached_property
    def _span_polynomials(self) -> tuple[list[float], list[tuple[tuple[float, ...], ...]]]:
        """The Taylor coefficients of every span as tuples of floats (the scalar path)."""
        lefts, coeffs = self._taylor_coefficients
        return lefts.tolist(), [tuple(tuple(float(v) for v in column) for column in span.T)
                                for span in np.transpose(coeffs, (2, 0, 1))]

    def point_and_derivatives(self, u: float) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """(x, x', x'') at one parameter value as tuples of floats: the per-cycle fast path."""
        lefts, polys = self._span_polynomials
        i = bisect.bisect_right(lefts, u) - 1
        if i < 0:
            i = 0
        t = u - lefts[i]
        a0, a1, a2 = [], [], []
        for c in polys[i]:  # one homogeneous coordinate: Horner for value, 1st and 2nd derivative
            v = d1 = d2 = 0.0
            for k in range(len(c) - 1, -1, -1):
                d2 = d2 * t + 2.0 * d1
                d1 = d1 * t + v
                v = v * t + c[k]
            a0.append(v)
            a1.append(d1)
            a2.append(d2)
        w, w1, w2 = a0[-1], a1[-1], a2[-1]
        inv = 1.0 / w
        x = tuple(a * inv for a in a0[:-1])
        dx = tuple((a - w1 * xi) * inv for a, xi in zip(a1, x))
        ddx = tuple((a - 2.0 * w1 * dxi - w2 * xi) * inv for a, dxi, xi in zip(a2, dx, x))
        return x, dx, ddx

    # ---- arc length (arc_length.ArcLength) ---------------------------------------------------
    @cached_property
    def _arc_length(self) -> ArcLength:
        lefts, coeffs = self._taylor_coefficients
        return ArcLength(lefts, coeffs, self.degree, self.breakpoints, EVALUATION_CHUNK)

    def speeds(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """|x'(u)| for an array of u (the integrand of the arc length)."""
        return self._arc_length.speeds(u)

    @property
    def length(self) -> float:
        """Total arc length (adaptive 16-point Gauss-Legendre on each knot span)."""
        return self._arc_length.length

    def arc_length(self, u: ArrayLike) -> NDArray[np.float64] | float:
        """Arc length from u_min to u (vectorised)."""
        return self._arc_length.arc_length(u)

    def u_at_arc_length(self, s: ArrayLike, tolerance_mm: float = 1e-10, max_iterations: int = 50) -> NDArray[np.float64] | float:
        """The parameter u with arc_length(u) = s (Newton safeguarded by bisection)."""
        return self._arc_length.u_at_arc_length(s, tolerance_mm, max_iterations)

    # ---- transformations --------------------------------------------------------------------
    def reversed(self) -> "NurbsCurve":
        """The same path traced from end to start (Wang eq. 18):
        w_r,i = w_{n-i}, P_r,i = P_{n-i}, u_r,i = (u_first + u_last) - u_{n+p+1-i}."""
        knots = (self.knots[0] + self.knots[-1]) - self.knots[::-1]
        return NurbsCurve.create(self.degree, self.control_points[::-1], self.weights[::-1], knots)

    def reparameterised(self, u_min: float, u_max: float) -> "NurbsCurve":
        """The same curve with its knot vector mapped linearly onto [u_min, u_max]."""
        scale = (u_max - u_min) / (self.u_max - self.u_min)
        return NurbsCurve.create(self.degree, self.control_points, self.weights, u_min + (self.knots - self.u_min) * scale)

    def __repr__(self) -> str:
        return (f"NurbsCurve(degree={self.degree}, points={len(self.control_points)}, dim={self.dim}, "
                f"u=[{self.u_min:g}, {self.u_max:g}])")
