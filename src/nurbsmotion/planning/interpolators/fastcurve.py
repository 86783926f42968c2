"""Per-cycle scalar evaluation of a 3-D NURBS curve of degree <= 3, in plain Python floats.

On one knot span the homogeneous curve A = [wx, wy, wz, w] is a polynomial of degree p,
so it is stored as its Taylor coefficients around the span's left knot (computed once with
the vectorised de Boor derivatives of NurbsCurve) and evaluated by Horner's rule, unrolled
for the cubic case (lower degrees are padded with zeros). The rational point and
derivatives follow from the quotient rule (reference §1):
  x' = (C' - W' x) / W,  x'' = (C'' - 2 W' x' - W'' x) / W.
About twice as fast as the general NurbsCurve.point_and_derivatives, and a point alone
(for Zhang's chord and midpoint) costs half of that again.
"""

from __future__ import annotations

from bisect import bisect_right
from math import factorial

import numpy as np

from nurbsmotion.geometry import NurbsCurve

MAX_FAST_DEGREE = 3


class FastCurve:
    """``point(u)`` and ``point_and_derivatives(u)`` of a curve, as tuples of floats."""

    def __init__(self, curve: NurbsCurve):
        if curve.dim != 3 or curve.degree > MAX_FAST_DEGREE:
            raise ValueError("FastCurve needs a 3-D curve of degree <= 3")
        if curve.degree == 1:  # lines and polylines: A is linear between consecutive control points
            nodes = curve.knots[1:-1]  # the parameter of each control point
            q = curve.homogeneous
            lefts = nodes[:-1]
            coeffs = np.zeros((len(lefts), 4, MAX_FAST_DEGREE + 1))
            coeffs[:, :, 0] = q[:-1]
            coeffs[:, :, 1] = (q[1:] - q[:-1]) / np.diff(nodes)[:, None]
        else:
            lefts = curve.breakpoints[:-1]
            derivs = curve.homogeneous_derivatives(np.asarray(lefts, dtype=float), order=curve.degree)
            coeffs = np.zeros((len(lefts), 4, MAX_FAST_DEGREE + 1))  # span, coordinate, power
            for k, a_k in enumerate(derivs):
                coeffs[:, :, k] = a_k.T / factorial(k)
        self.lefts = [float(v) for v in lefts]
        self.spans = [tuple(float(v) for v in span.ravel()) for span in coeffs]
        self.u_min, self.u_max = curve.u_min, curve.u_max

    def _span(self, u: float) -> tuple[float, tuple[float, ...]]:
        i = bisect_right(self.lefts, u) - 1
        if i < 0:
            i = 0
        return u - self.lefts[i], self.spans[i]

    def point(self, u: float) -> tuple[float, float, float]:
        t, c = self._span(u)
        w = ((c[15] * t + c[14]) * t + c[13]) * t + c[12]
        inv = 1.0 / w
        return ((((c[3] * t + c[2]) * t + c[1]) * t + c[0]) * inv,
                (((c[7] * t + c[6]) * t + c[5]) * t + c[4]) * inv,
                (((c[11] * t + c[10]) * t + c[9]) * t + c[8]) * inv)

    def point_and_derivatives(self, u: float) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        t, c = self._span(u)
        t2 = t * t
        w = ((c[15] * t + c[14]) * t + c[13]) * t + c[12]
        w1 = (3.0 * c[15] * t + 2.0 * c[14]) * t + c[13]
        w2 = 6.0 * c[15] * t + 2.0 * c[14]
        inv = 1.0 / w
        ax = c[3] * t2 * t + c[2] * t2 + c[1] * t + c[0]
        ay = c[7] * t2 * t + c[6] * t2 + c[5] * t + c[4]
        az = c[11] * t2 * t + c[10] * t2 + c[9] * t + c[8]
        x, y, z = ax * inv, ay * inv, az * inv
        dx = ((3.0 * c[3] * t + 2.0 * c[2]) * t + c[1] - w1 * x) * inv
        dy = ((3.0 * c[7] * t + 2.0 * c[6]) * t + c[5] - w1 * y) * inv
        dz = ((3.0 * c[11] * t + 2.0 * c[10]) * t + c[9] - w1 * z) * inv
        ddx = (6.0 * c[3] * t + 2.0 * c[2] - 2.0 * w1 * dx - w2 * x) * inv
        ddy = (6.0 * c[7] * t + 2.0 * c[6] - 2.0 * w1 * dy - w2 * y) * inv
        ddz = (6.0 * c[11] * t + 2.0 * c[10] - 2.0 * w1 * dz - w2 * z) * inv
        return (x, y, z), (dx, dy, dz), (ddx, ddy, ddz)


def scalar_evaluators(curve: NurbsCurve):
    """(point_and_derivatives, point) for the per-cycle loops: FastCurve when it applies."""
    if curve.dim == 3 and curve.degree <= MAX_FAST_DEGREE:
        fast = FastCurve(curve)
        return fast.point_and_derivatives, fast.point
    return curve.point_and_derivatives, lambda u: curve.point_and_derivatives(u)[0]
