"""Corner blends (geometry/corner_blend.py): G2 joins, within the tolerance, no loops, at most
half a piece. The distances here are brute force: the blend sampled densely, lines by
projection, arcs sampled densely as their NURBS."""

from __future__ import annotations

import numpy as np
import pytest

from nurbsmotion.geometry import corner_blend as cb
from nurbsmotion.geometry.primitives import arc_curve, line_curve

TOL = 0.01
DENSE = np.linspace(0.0, 1.0, 20001)


def corner(theta_deg: float, length: float = 10.0) -> tuple[cb.Pieces, cb.Pieces, np.ndarray]:
    """Two lines meeting at the origin, the second turned by theta; and its polyline."""
    th = np.radians(theta_deg)
    a, v, b = np.array([-length, 0.0, 0.0]), np.zeros(3), length * np.array([np.cos(th), np.sin(th), 0.0])
    return cb.line_pieces(a[None], v[None]), cb.line_pieces(v[None], b[None]), np.array([a, v, b])


def segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip((q - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(q - a - t[:, None] * ab, axis=1)


def curve_distance(q: np.ndarray, curve) -> np.ndarray:
    pts = curve.points(np.linspace(curve.u_min, curve.u_max, 40001))
    return np.array([np.min(np.linalg.norm(pts - x, axis=1)) for x in q])


def frame(curve, u: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x, d1, d2 = curve.derivatives(u, 2)
    speed = np.linalg.norm(d1)
    t = d1 / speed
    return x, t, (d2 - (d2 @ t) * t) / speed**2


@pytest.mark.parametrize("theta_deg", [5.0, 30.0, 90.0, 135.0])
def test_a_line_line_blend_is_within_the_tolerance_g2_and_at_most_half_a_segment(theta_deg):
    incoming, outgoing, poly = corner(theta_deg, length=0.05 if theta_deg == 5.0 else 10.0)
    d = cb.trim_distances(incoming, outgoing, np.array([TOL]))
    assert 0.0 < d[0] <= 0.5 * 0.05 if theta_deg == 5.0 else 0.0 < d[0]
    assert d[0] <= 0.5 * min(incoming.length_mm[0], outgoing.length_mm[0])
    points = cb.blend_points(incoming, outgoing, d)
    assert cb.monotone(points)[0]
    curve = cb.bezier_curve(points[0])
    q = curve.points(DENSE)
    deviation = np.minimum(segment_distance(q, poly[0], poly[1]), segment_distance(q, poly[1], poly[2]))
    assert deviation.max() <= TOL
    if theta_deg != 5.0:  # not cut short by the segments: the tolerance is used
        assert deviation.max() >= 0.95 * TOL
    # G2: position, unit tangent and curvature vector (0 on a line) equal at both joins
    x0, t0, k0 = frame(curve, 0.0)
    x1, t1, k1 = frame(curve, 1.0)
    np.testing.assert_allclose(x0, poly[1] - d[0] * (poly[1] - poly[0]) / np.linalg.norm(poly[1] - poly[0]), atol=1e-12)
    np.testing.assert_allclose(t0, [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(t1, (poly[2] - poly[1]) / np.linalg.norm(poly[2] - poly[1]), atol=1e-12)
    assert np.linalg.norm(k0) <= 1e-9 * np.max(curve.curvature(DENSE)) and np.linalg.norm(k1) <= 1e-9 * np.max(
        curve.curvature(DENSE))


def test_the_middle_is_the_farthest_point_of_a_line_line_blend_at_every_deflection():
    """What middle_deviation relies on: between two lines the blend is symmetric and its
    middle is its farthest point from them (dense samples, every degree up to 150)."""
    assert cb_max_deflection() <= 150.0
    for theta in np.arange(1.0, 151.0, 1.0):  # beyond the planner's MAX_DEFLECTION_DEG
        incoming, outgoing, poly = corner(float(theta))
        points = cb.blend_points(incoming, outgoing, np.array([1.0]))
        q = cb.bezier_curve(points[0]).points(DENSE)
        deviation = np.minimum(segment_distance(q, poly[0], poly[1]), segment_distance(q, poly[1], poly[2]))
        assert deviation.max() <= cb.middle_deviation(incoming, outgoing, np.array([1.0]))[0] * (1 + 1e-12)
        assert cb.monotone(points)[0]


def cb_max_deflection() -> float:
    from nurbsmotion.planning.lookahead.blend import MAX_DEFLECTION_DEG
    return MAX_DEFLECTION_DEG


def arc_pieces_of(curve) -> cb.Pieces:
    arc = cb.arc_of(curve)
    assert arc is not None
    return cb.arc_pieces([arc])


@pytest.mark.parametrize("kind", ["line-arc", "arc-line", "arc-arc"])
def test_blends_with_arcs_are_within_the_tolerance_and_g2(kind):
    line_in = line_curve([-5.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    arc_out = arc_curve([0.0, 3.0, 0.0], [0.0, 0.0, 0.0], -np.pi / 2)  # leaves along +x turning right... then
    arc_in = arc_curve([-3.0, 0.0, 0.0], [-3.0, -3.0, 0.0], np.pi / 2)  # arrives at the origin along +y
    line_out = line_curve([0.0, 0.0, 0.0], [5.0, 0.0, 0.0])
    arc_out2 = arc_curve([2.0, 0.0, 0.0], [0.0, 0.0, 0.0], np.pi / 2)  # leaves along -y
    first, second = {"line-arc": (line_in, arc_curve([4.0, 0.0, 0.0], [0.0, 0.0, 0.0], -np.pi / 2)),
                     "arc-line": (arc_in, line_out), "arc-arc": (arc_in, arc_out2)}[kind]
    del arc_out
    shapes = [cb.line_pieces(c.control_points[:1], c.control_points[-1:]) if c.degree == 1 else arc_pieces_of(c)
              for c in (first, second)]
    d = cb.trim_distances(shapes[0], shapes[1], np.array([TOL]))
    assert 0.0 < d[0] <= 0.5 * min(first.length, second.length)
    points = cb.blend_points(shapes[0], shapes[1], d)
    assert cb.monotone(points)[0]
    blend = cb.bezier_curve(points[0])
    q = blend.points(np.linspace(0, 1, 401))
    deviation = np.minimum(curve_distance(q, first), curve_distance(q, second))
    assert deviation.max() <= TOL * (1 + 1e-6)
    assert deviation.max() >= 0.9 * TOL
    u_in = first.u_at_arc_length(first.length - d[0])
    u_out = second.u_at_arc_length(d[0])
    for (x_a, t_a, k_a), (x_b, t_b, k_b) in ((frame(first, u_in), frame(blend, 0.0)),
                                             (frame(second, u_out), frame(blend, 1.0))):
        np.testing.assert_allclose(x_a, x_b, atol=1e-9)
        np.testing.assert_allclose(t_a, t_b, atol=1e-9)
        scale = max(np.linalg.norm(k_a), np.linalg.norm(k_b), 1e-300)
        assert np.linalg.norm(k_a - k_b) <= 1e-6 * scale or np.linalg.norm(k_a - k_b) <= 1e-9


def test_arc_of_finds_planar_arcs_and_refuses_helices():
    arc = cb.arc_of(arc_curve([1.0, 2.0, 0.0], [4.0, 2.0, 0.0], 3.0))
    assert arc is not None
    np.testing.assert_allclose(arc.center, [1.0, 2.0, 0.0], atol=1e-12)
    assert arc.radius == pytest.approx(3.0) and arc.sweep_rad == pytest.approx(3.0)
    assert cb.arc_of(arc_curve([1.0, 2.0, 0.0], [4.0, 2.0, 0.0], 3.0, rise_mm=1.0)) is None
    assert cb.arc_of(line_curve([0, 0, 0], [1, 0, 0])) is None


def test_a_quintic_bezier_evaluates_like_its_control_polygon_says():
    """The one-span Taylor coefficients (nurbs.bezier_taylor) against the Bernstein sum."""
    rng = np.random.default_rng(3)
    points = rng.normal(size=(6, 3))
    curve = cb.bezier_curve(points)
    t = np.linspace(0.0, 1.0, 11)
    binom = np.array([1, 5, 10, 10, 5, 1])
    k = np.arange(6)
    bernstein = binom * t[:, None] ** k * (1 - t[:, None]) ** (5 - k)
    np.testing.assert_allclose(curve.points(t), bernstein @ points, atol=1e-12)


def test_curvature_peaks_are_the_curves_own_at_the_samples():
    """curvature_peaks: the largest curvature of the sampled blend equals NurbsCurve.curvature
    there; the slope |dc/ds| of a blend between two lines scales with 1 / d^2 (its shape only
    scales with d)."""
    incoming, outgoing, _ = corner(90.0)
    d = np.array([1.0, 0.5])
    two = cb.Pieces(*(np.concatenate([getattr(incoming, f)] * 2) for f in cb.PIECE_FIELDS))
    two_out = cb.Pieces(*(np.concatenate([getattr(outgoing, f)] * 2) for f in cb.PIECE_FIELDS))
    points = cb.blend_points(two, two_out, d)
    kappa, slope = cb.curvature_peaks(points)
    samples = np.linspace(0.0, 1.0, 65)
    assert kappa[0] == pytest.approx(cb.bezier_curve(points[0]).curvature(samples).max(), rel=1e-9)
    assert kappa[1] == pytest.approx(2.0 * kappa[0], rel=1e-9)
    assert slope[1] == pytest.approx(4.0 * slope[0], rel=1e-9)
