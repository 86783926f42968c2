"""Curvature-continuous (G2) corner blends between lines and planar circular arcs.

A corner between two pieces is replaced by a quintic Bezier curve (a degree-5 NURBS with
unit weights): the quintic Hermite that matches, at both trim points P0 (on the incoming
piece) and P1 (on the outgoing one), the position, the unit tangent t times L and the
curvature vector k times L^2 (no tangential part, so |x'| = L and x'' = k L^2 there). L is
the chord |P1 - P0| times TANGENT_SCALE between two lines (zero curvature at both ends: 1.2
turns a 90 deg corner within the tolerance at ~4 % more speed than 1.0 without a jerk limit
and ~30 % more with one, the curvature's slope being 2.4x smaller), and the arc length of
the circle through P0, P1 with those end tangents, chord (phi/2) / sin(phi/2), where an end
is curved (an arc, or two blends meeting on a short line, blend.py): on a polygon along a
circle the blend's curvature is then constant to 1e-3 (1.2 would swing it +-40 %, and its
slope would limit the speed with a jerk limit 8x). Its control points are

  b0 = P0, b1 = P0 + D0 / 5, b2 = P0 + 2 D0 / 5 + S0 / 20,
  b3 = P1 - 2 D1 / 5 + S1 / 20, b4 = P1 - D1 / 5, b5 = P1,   D = L t, S = L^2 k

(B'(0) = 5 (b1 - b0) = D0, B''(0) = 20 (b2 - 2 b1 + b0) = S0, mirrored at the end). So the
blend meets both pieces in position, tangent and curvature vector: the path is G2 there.

The blend is sized by its trim distance d, the arc length cut from each piece at the corner
(the same on both sides; at most SHARE_LIMIT of either piece, so the blends at the two ends
of a piece never overlap). The largest distance of the blend from the two original pieces
(sampled at DEVIATION_SAMPLES points of the Bezier, the distance to lines and arcs exact)
must stay within the tolerance: between two lines the shape only scales with d, so the
deviation is d f(theta) and one evaluation sizes it; with an arc, a bisection on d (all
junctions at once). A blend whose progress along its chord is not monotone (a loop or a
cusp) is rejected: that corner stays a junction of the two pieces as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry.nurbs import NurbsCurve

TANGENT_SCALE = 1.2  # |x'| at both ends of the blend: this x its chord
SHARE_LIMIT = 0.49  # largest part of a piece one blend takes (two blends leave >= 2 % of it)
DEVIATION_SAMPLES = 129  # points of the blend whose distance from the pieces is measured (odd: the middle)
TOLERANCE_SHARE = 0.98  # the blend is sized to this x the tolerance (the sampling's margin)
BISECTION_STEPS = 30
ARC_PLANE_TOLERANCE = 1e-9  # relative: an arc's control points off its plane (a helix) are not blended
BEZIER_KNOTS = np.array([0.0] * 6 + [1.0] * 6)
BEZIER_KNOTS.setflags(write=False)


def _bernstein(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """(len(t), 6) quintic Bernstein polynomials at t."""
    s = 1.0 - t
    binom = np.array([1.0, 5.0, 10.0, 10.0, 5.0, 1.0])
    k = np.arange(6)
    return binom * t[:, None] ** k * s[:, None] ** (5 - k)


_T = np.linspace(0.0, 1.0, DEVIATION_SAMPLES)
_BASIS = _bernstein(_T)


def _bernstein4(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """(len(t), 5) quartic Bernstein polynomials at t (the quintic's derivative basis)."""
    s = 1.0 - t
    binom = np.array([1.0, 4.0, 6.0, 4.0, 1.0])
    k = np.arange(5)
    return binom * t[:, None] ** k * s[:, None] ** (4 - k)


_MONOTONE_T = np.linspace(0.0, 1.0, 33)
_B4 = _bernstein4(_MONOTONE_T)
_MIDDLE = _bernstein(np.array([0.5]))[0]


def control_points(p0: NDArray[np.float64], t0: NDArray[np.float64], k0: NDArray[np.float64],
                   p1: NDArray[np.float64], t1: NDArray[np.float64], k1: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 6, 3) control points of the quintic blends (module docstring) from the trim points,
    unit tangents and curvature vectors at both ends, each (n, 3)."""
    chord = np.linalg.norm(p1 - p0, axis=1)
    half = 0.5 * np.arccos(np.clip(np.einsum("ij,ij->i", t0, t1), -1.0, 1.0))  # half the turn
    arc = np.where(half > 1e-8, half / np.maximum(np.sin(half), 1e-300), 1.0)  # arc / chord of a circle
    curved = np.any(k0 != 0.0, axis=1) | np.any(k1 != 0.0, axis=1)
    length = (chord * np.where(curved, arc, TANGENT_SCALE))[:, None]
    d0, d1 = length * t0, length * t1
    s0, s1 = length * length * k0, length * length * k1
    return np.stack([p0, p0 + d0 / 5.0, p0 + 2.0 * d0 / 5.0 + s0 / 20.0,
                     p1 - 2.0 * d1 / 5.0 + s1 / 20.0, p1 - d1 / 5.0, p1], axis=1)


_UNIT_WEIGHTS = np.ones(6)
_UNIT_WEIGHTS.setflags(write=False)


def bezier_curve(points: NDArray[np.float64]) -> NurbsCurve:
    """A quintic Bezier (6 control points) as a degree-5 NURBS on [0, 1]: valid by
    construction when the points are finite (NurbsCurve.create names the problem otherwise)."""
    points = np.array(points, dtype=np.float64)
    if points.shape != (6, 3) or not np.isfinite(points).all():
        return NurbsCurve.create(5, points, _UNIT_WEIGHTS, BEZIER_KNOTS)
    points.setflags(write=False)
    return NurbsCurve(5, points, _UNIT_WEIGHTS, BEZIER_KNOTS)


def bezier_points(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, DEVIATION_SAMPLES, 3) points of the blends (n, 6, 3) at equal steps in t."""
    return np.einsum("mk,nkd->nmd", _BASIS, points)


def monotone(points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n,) True where the blend's derivative points forward along its chord at every sample
    (its projection on the chord only grows: no loop, no cusp)."""
    chord = points[:, 5] - points[:, 0]
    deriv = 5.0 * np.einsum("mk,nkd->nmd", _B4, np.diff(points, axis=1))
    return np.all(np.einsum("nmd,nd->nm", deriv, chord) > 0.0, axis=1)


_PEAK_T = np.linspace(0.0, 1.0, 65)
_PEAK_B4 = _bernstein4(_PEAK_T)
_PEAK_B3 = np.array([1.0, 3.0, 3.0, 1.0]) * _PEAK_T[:, None] ** np.arange(4) * (1.0 - _PEAK_T[:, None]) ** (3 - np.arange(4))


def curvature_samples(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(curvature vectors c (n, PEAK, 3), arc length between consecutive samples (n, PEAK - 1))
    of each blend (control points (n, 6, 3)) at PEAK samples equally spaced in t:
    c = (x'' - (x'' . t) t) / |x'|^2, s by the trapezoid rule on |x'|."""
    d1 = 5.0 * np.einsum("mk,nkd->nmd", _PEAK_B4, np.diff(points, axis=1))
    d2 = 20.0 * np.einsum("mk,nkd->nmd", _PEAK_B3, np.diff(points, n=2, axis=1))
    speed = np.maximum(np.linalg.norm(d1, axis=2), 1e-300)
    t = d1 / speed[..., None]
    c = (d2 - np.einsum("nmd,nmd->nm", d2, t)[..., None] * t) / (speed**2)[..., None]
    return c, 0.5 * (speed[:, 1:] + speed[:, :-1]) * np.diff(_PEAK_T)


def curvature_peaks(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(largest curvature |c|, largest slope |dc/ds| of the curvature vector) of each blend
    (control points (n, 6, 3)), from its curvature_samples."""
    c, ds = curvature_samples(points)
    slope = np.linalg.norm(np.diff(c, axis=1), axis=2) / np.maximum(ds, 1e-300)
    return np.linalg.norm(c, axis=2).max(axis=1), slope.max(axis=1)


@dataclass(frozen=True)
class Pieces:
    """Lines and planar circular arcs, one per junction side, parametrised by arc length
    sigma in [0, length_mm]: a line A + sigma t; an arc C + r (cos(sigma / r) e1 + sin(sigma / r) e2)."""

    is_arc: NDArray[np.bool_]  # (n,)
    start: NDArray[np.float64]  # (n, 3) A (lines)
    direction: NDArray[np.float64]  # (n, 3) unit t (lines)
    center: NDArray[np.float64]  # (n, 3) C (arcs)
    e1: NDArray[np.float64]  # (n, 3) unit, C -> start (arcs)
    e2: NDArray[np.float64]  # (n, 3) unit, normal x e1: the direction of motion at the start (arcs)
    radius: NDArray[np.float64]  # (n,) (arcs; 1 for lines)
    length_mm: NDArray[np.float64]  # (n,)

    def take(self, index: NDArray[np.intp]) -> "Pieces":
        return Pieces(*(getattr(self, f)[index] for f in PIECE_FIELDS))

    def state_at(self, sigma: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(point, unit tangent, curvature vector) at arc length sigma, each (n, 3)."""
        angle = (sigma / self.radius)[:, None]
        c, s = np.cos(angle), np.sin(angle)
        radial = c * self.e1 + s * self.e2
        arc = self.is_arc[:, None]
        point = np.where(arc, self.center + self.radius[:, None] * radial, self.start + sigma[:, None] * self.direction)
        tangent = np.where(arc, -s * self.e1 + c * self.e2, self.direction)
        curvature = np.where(arc, -radial / self.radius[:, None], 0.0)
        return point, tangent, curvature

    def distance(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """(n, m) distance of points q (n, m, 3) from each piece (exact for lines and arcs)."""
        a = self.start[:, None, :]
        t = self.direction[:, None, :]
        along = np.clip(np.einsum("nmd,nd->nm", q - a, self.direction), 0.0, self.length_mm[:, None])
        line = np.linalg.norm(q - a - along[..., None] * t, axis=2)
        rel = q - self.center[:, None, :]
        x = np.einsum("nmd,nd->nm", rel, self.e1)
        y = np.einsum("nmd,nd->nm", rel, self.e2)
        normal = np.cross(self.e1, self.e2)
        h = np.einsum("nmd,nd->nm", rel, normal)
        rho = np.hypot(x, y)
        sweep = (self.length_mm / self.radius)[:, None]
        angle = np.mod(np.arctan2(y, x), 2.0 * np.pi)
        inside = angle <= sweep
        on_circle = np.hypot(h, rho - self.radius[:, None])
        end = self.center + self.radius[:, None] * (np.cos(sweep) * self.e1 + np.sin(sweep) * self.e2)
        ends = np.minimum(np.linalg.norm(q - (self.center + self.radius[:, None] * self.e1)[:, None, :], axis=2),
                          np.linalg.norm(q - end[:, None, :], axis=2))
        arc = np.where(inside, on_circle, ends)
        return np.where(self.is_arc[:, None], arc, line)


def blend_points(incoming: Pieces, outgoing: Pieces, d: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 6, 3) control points of the blends that trim d from both pieces."""
    p0, t0, k0 = incoming.state_at(incoming.length_mm - d)
    p1, t1, k1 = outgoing.state_at(d)
    return control_points(p0, t0, k0, p1, t1, k1)


def sampled_deviation(incoming: Pieces, outgoing: Pieces, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest distance of each blend (control points (n, 6, 3)) from its two pieces, at
    DEVIATION_SAMPLES points."""
    q = bezier_points(points)
    return np.minimum(incoming.distance(q), outgoing.distance(q)).max(axis=1)


def blend_deviation(incoming: Pieces, outgoing: Pieces, d: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(largest distance of each blend from its two pieces, sampled, and its control points
    (n, 6, 3)) for trim distances d."""
    points = blend_points(incoming, outgoing, d)
    return sampled_deviation(incoming, outgoing, points), points


def end_state(points: NDArray[np.float64], start: bool) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(point, unit tangent, curvature vector) at the start or the end of a blend from its
    control points (6, 3): the inverse of control_points (x' = 5 (b1 - b0), x'' = 20 (b2 - 2 b1
    + b0), no tangential part in x'')."""
    b = points if start else points[::-1]
    derivative = 5.0 * (b[1] - b[0])  # the end's x' reversed
    length = float(np.linalg.norm(derivative))
    tangent = derivative / length if start else -derivative / length
    return b[0].copy(), tangent, 20.0 * (b[2] - 2.0 * b[1] + b[0]) / (length * length)


def middle_deviation(incoming: Pieces, outgoing: Pieces, d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of each blend's middle point B(1/2) from its two pieces: the largest distance
    of a blend between two lines (symmetric about the corner's bisector; the tests measure it
    densely at every deflection up to MAX_DEFLECTION)."""
    middle = np.einsum("k,nkd->nd", _MIDDLE, blend_points(incoming, outgoing, d))[:, None, :]
    return np.minimum(incoming.distance(middle), outgoing.distance(middle))[:, 0]


def trim_distances(incoming: Pieces, outgoing: Pieces, tolerance_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest trim distance d per junction (at most SHARE_LIMIT of either piece) whose blend
    stays within TOLERANCE_SHARE x tolerance of the pieces (module docstring); 0 where none does.
    Between two lines the deviation is d f(theta): measured once at the largest d and scaled;
    with an arc, bisection on the densely sampled deviation."""
    d_max = SHARE_LIMIT * np.minimum(incoming.length_mm, outgoing.length_mm)
    target = TOLERANCE_SHARE * tolerance_mm
    lines = ~(incoming.is_arc | outgoing.is_arc)
    d = d_max.copy()
    index = np.flatnonzero(lines)
    if len(index):
        deviation = middle_deviation(incoming.take(index), outgoing.take(index), d_max[index])
        scale = np.divide(target[index], deviation, out=np.ones_like(deviation), where=deviation > 0)
        d[index] = d_max[index] * np.minimum(scale, 1.0)
    index = np.flatnonzero(~lines)
    if len(index):
        inc, out = incoming.take(index), outgoing.take(index)
        hi = d_max[index]
        ok = blend_deviation(inc, out, hi)[0] <= target[index]
        lo = np.where(ok, hi, 0.0)
        for _ in range(BISECTION_STEPS):
            todo = np.flatnonzero(~ok)
            if len(todo) == 0:
                break
            mid = 0.5 * (lo[todo] + hi[todo])
            passed = blend_deviation(inc.take(todo), out.take(todo), mid)[0] <= target[index][todo]
            lo[todo] = np.where(passed, mid, lo[todo])
            hi[todo] = np.where(passed, hi[todo], mid)
        d[index] = lo
    return d


def line_pieces(start: NDArray[np.float64], end: NDArray[np.float64]) -> Pieces:
    """Pieces for lines from start to end (n, 3)."""
    n = len(start)
    delta = end - start
    length = np.linalg.norm(delta, axis=1)
    zeros = np.zeros((n, 3))
    return Pieces(np.zeros(n, dtype=bool), start, delta / np.maximum(length, 1e-300)[:, None], zeros, zeros, zeros,
                  np.ones(n), length)


@dataclass(frozen=True)
class Arc:
    """A planar circular arc: center, unit e1 (to the start), unit e2 (direction of motion at
    the start), radius, sweep (> 0)."""

    center: NDArray[np.float64]
    e1: NDArray[np.float64]
    e2: NDArray[np.float64]
    radius: float
    sweep_rad: float


def arc_of(curve: NurbsCurve) -> Arc | None:
    """The circular arc a NURBS curve is exactly (primitives.arc_curve: degree 2, weights 1, w,
    1, w, ..., 1 with w = cos(delta / 2) < 1, all points in one plane), or None."""
    if curve.degree != 2 or len(curve.control_points) < 3 or len(curve.control_points) % 2 == 0:
        return None
    w = curve.weights
    if not (np.all(w[::2] == 1.0) and np.all(w[1::2] == w[1]) and 0.0 < w[1] < 1.0):
        return None
    points = np.zeros((len(curve.control_points), 3))
    points[:, : min(3, curve.dim)] = curve.control_points[:, :3]
    p0, p1, p2 = points[0], points[1], points[2]
    mid = 0.5 * (p0 + p2)
    to_mid = mid - p1
    if not np.dot(to_mid, to_mid) > 0:
        return None
    center = p1 + to_mid * (np.dot(p1 - p0, p1 - p0) / np.dot(to_mid, to_mid))
    radius = float(np.linalg.norm(p0 - center))
    normal = np.cross(p0 - center, p1 - p0)
    norm = float(np.linalg.norm(normal))
    if not radius > 0 or not norm > 0:
        return None
    normal /= norm
    scale = ARC_PLANE_TOLERANCE * max(radius, 1.0)
    ends = points[::2]
    if np.any(np.abs((points - center) @ normal) > scale) or np.any(
            np.abs(np.linalg.norm(ends - center, axis=1) - radius) > scale):
        return None  # a helix (rises along the normal) or not a circle
    e1 = (p0 - center) / radius
    e2 = np.cross(normal, e1)
    segments = (len(points) - 1) // 2
    return Arc(center, e1, e2, radius, float(segments * 2.0 * np.arccos(w[1])))


def arc_pieces(arcs: list[Arc]) -> Pieces:
    """Pieces for circular arcs."""
    n = len(arcs)
    zeros = np.zeros((n, 3))
    radius = np.array([a.radius for a in arcs])
    return Pieces(np.ones(n, dtype=bool), zeros, zeros, np.array([a.center for a in arcs]).reshape(n, 3),
                  np.array([a.e1 for a in arcs]).reshape(n, 3), np.array([a.e2 for a in arcs]).reshape(n, 3),
                  radius, radius * np.array([a.sweep_rad for a in arcs]))


PIECE_FIELDS = ("is_arc", "start", "direction", "center", "e1", "e2", "radius", "length_mm")
