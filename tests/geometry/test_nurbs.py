"""NurbsCurve: evaluation against scipy, derivatives, curvature, arc length, reversal, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline

from nurbsmotion.geometry import CurveError, NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve

from ..conftest import WANG_LENGTH_MM


@st.composite
def random_curves(draw) -> NurbsCurve:
    degree = draw(st.integers(1, 5))
    n_points = draw(st.integers(degree + 1, degree + 8))
    dim = draw(st.integers(1, 6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    points = rng.uniform(-100, 100, (n_points, dim))
    weights = rng.uniform(0.2, 5.0, n_points)
    u0 = draw(st.floats(-10, 10))
    width = draw(st.floats(0.1, 50))
    n_inner = n_points - degree - 1
    inner = np.sort(rng.uniform(u0, u0 + width, n_inner))
    if n_inner >= 2 and draw(st.booleans()):
        inner[1] = inner[0]  # a double interior knot (allowed for degree >= 2)
        if degree < 2:
            inner = np.sort(rng.uniform(u0, u0 + width, n_inner))
    knots = np.concatenate([[u0] * (degree + 1), inner, [u0 + width] * (degree + 1)])
    return NurbsCurve.create(degree, points, weights, knots)


def scipy_rational(curve: NurbsCurve, u: np.ndarray) -> list[np.ndarray]:
    """x, x', x'' from scipy's B-spline of the homogeneous control points (independent code)."""
    spline = BSpline(curve.knots, curve.homogeneous, curve.degree)
    a = [spline(u, nu) for nu in range(3)]
    w = [ai[:, -1:] for ai in a]
    x = a[0][:, :-1] / w[0]
    x1 = (a[1][:, :-1] - w[1] * x) / w[0]
    x2 = (a[2][:, :-1] - 2 * w[1] * x1 - w[2] * x) / w[0]
    return [x, x1, x2]


@settings(max_examples=150, deadline=None)
@given(random_curves(), st.integers(0, 2**32 - 1))
def test_evaluation_matches_scipy_bspline(curve, seed):
    u = np.random.default_rng(seed).uniform(curve.u_min, curve.u_max, 200)
    u = np.concatenate([u, curve.breakpoints])
    ours = curve.derivatives(u, 2)
    for k, ref in enumerate(scipy_rational(curve, u)):
        if k > curve.degree:
            continue
        scale = max(1.0, np.abs(ref).max())
        np.testing.assert_allclose(ours[k], ref, atol=1e-9 * scale, rtol=0)


@settings(max_examples=60, deadline=None)
@given(random_curves(), st.floats(0.02, 0.98))
def test_scalar_path_equals_vectorised(curve, fraction):
    u = curve.u_min + fraction * (curve.u_max - curve.u_min)
    vec = curve.derivatives(u, 2)
    scalar = curve.point_and_derivatives(u)
    for k in range(3):
        scale = max(1.0, np.abs(vec[k]).max())
        np.testing.assert_allclose(np.array(scalar[k]), vec[k], atol=1e-8 * scale, rtol=0)


@settings(max_examples=60, deadline=None)
@given(random_curves(), st.floats(0.05, 0.95))
def test_derivatives_match_finite_differences(curve, fraction):
    # Stay inside one knot span: derivatives jump at knots.
    spans = curve.breakpoints
    i = int(np.clip(np.searchsorted(spans, spans[0] + fraction * (spans[-1] - spans[0])) - 1, 0, len(spans) - 2))
    a, b = spans[i], spans[i + 1]
    u = a + 0.5 * (b - a)
    h = 1e-4 * (b - a)
    values = curve.derivatives(np.array([u - h, u, u + h]), 3)
    fd1 = (values[0, 2] - values[0, 0]) / (2 * h)
    fd2 = (values[1, 2] - values[1, 0]) / (2 * h)
    fd3 = (values[2, 2] - values[2, 0]) / (2 * h)
    for analytic, numeric in ((values[1, 1], fd1), (values[2, 1], fd2), (values[3, 1], fd3)):
        scale = max(1.0, np.abs(analytic).max(), np.abs(numeric).max())
        np.testing.assert_allclose(analytic, numeric, atol=1e-4 * scale, rtol=0)


def test_circle_is_exact():
    circle = arc_curve(center=(1.0, 2.0, 3.0), start=(6.0, 2.0, 3.0), sweep_rad=2 * math.pi)
    u = np.linspace(0, 1, 10_001)
    points = circle.points(u)
    radius = np.linalg.norm(points - [1.0, 2.0, 3.0], axis=1)
    assert np.abs(radius - 5.0).max() < 1e-12 * 5
    assert np.abs(circle.curvature(u) - 0.2).max() < 1e-12
    assert circle.length == pytest.approx(2 * math.pi * 5.0, rel=1e-12)


@pytest.mark.parametrize("sweep", [0.3, math.pi / 2, 2.0, -3.0, 5.5])
def test_arcs_have_exact_length_and_end_point(sweep):
    # Turning (y, z) = (3, 0) about +X by `sweep` gives (3 cos, 3 sin); x = 0.5 is kept.
    arc = arc_curve(center=(0, 0, 0), start=(0.5, 3.0, 0.0), sweep_rad=sweep, normal=(1, 0, 0))
    assert arc.length == pytest.approx(3.0 * abs(sweep), rel=1e-10)
    np.testing.assert_allclose(arc.points(1.0), [0.5, 3.0 * math.cos(sweep), 3.0 * math.sin(sweep)], atol=1e-12)
    mid = arc.points(np.linspace(0, 1, 101))
    np.testing.assert_allclose(np.hypot(mid[:, 1], mid[:, 2]), 3.0, atol=1e-12)


def test_wang_curve_length(wang_curve):
    assert wang_curve.length == pytest.approx(WANG_LENGTH_MM, abs=0.05)
    # Gauss-Legendre against scipy's adaptive quadrature per knot span: relative error < 1e-9.
    from scipy.integrate import quad

    def speed(u: float) -> float:
        return float(np.linalg.norm(wang_curve.derivatives(u, 1)[1]))

    spans = wang_curve.breakpoints
    reference = sum(quad(speed, a, b, epsabs=1e-11, epsrel=1e-13, limit=200)[0] for a, b in zip(spans[:-1], spans[1:]))
    assert abs(wang_curve.length - reference) / reference < 1e-9


def test_u_at_arc_length_inverts_arc_length(wang_curve):
    s = np.linspace(0, wang_curve.length, 2001)
    u = wang_curve.u_at_arc_length(s)
    assert np.all(np.diff(u) > 0)
    assert np.abs(wang_curve.arc_length(u) - s).max() < 1e-9
    assert wang_curve.u_at_arc_length(0.0) == wang_curve.u_min
    assert wang_curve.u_at_arc_length(wang_curve.length) == pytest.approx(wang_curve.u_max, abs=1e-12)


def test_reversed_curve_traces_the_same_path_backwards(wang_curve):
    rev = wang_curve.reversed()
    u = np.linspace(0, 1, 101)
    np.testing.assert_allclose(rev.points(u), wang_curve.points(1 - u), atol=1e-12)
    assert rev.length == pytest.approx(wang_curve.length, rel=1e-12)
    np.testing.assert_allclose(rev.reversed().knots, wang_curve.knots, atol=1e-15)


@pytest.mark.parametrize(
    "kwargs, field, fragment",
    [
        (dict(degree=0, control_points=[(0, 0), (1, 1)]), "degree", "between 1 and"),
        (dict(degree=3, control_points=[(0, 0), (1, 1)]), "control_points", "at least 4"),
        (dict(degree=1, control_points=[(0, 0), (1, 1)], weights=[1, 0]), "weights", "weight 2 is 0"),
        (dict(degree=1, control_points=[(0, 0), (1, 1)], weights=[1, float("nan")]), "weights", "not a finite"),
        (dict(degree=1, control_points=[(0, 0), (1, 1)], knots=[0, 0, 1]), "knots", "need 4 knots"),
        (dict(degree=1, control_points=[(0, 0), (1, 1), (2, 0)], knots=[0, 0, 0.7, 0.5, 1]), "knots", "must not decrease"),
        (dict(degree=2, control_points=[(0, 0), (1, 1), (2, 0)], knots=[0, 0, 0.1, 1, 1, 1]), "knots", "clamped"),
        (dict(degree=1, control_points=[(0, 0), (1, 1)], knots=[1, 1, 1, 1]), "knots", "empty"),
        (dict(degree=2, control_points=[(0, 0)] * 6, knots=[0, 0, 0, .5, .5, .5, 1, 1, 1]), "knots", "repeats 3 times"),
        (dict(degree=1, control_points=[(0,) * 7, (1,) * 7]), "control_points", "1 to 6 coordinates"),
        (dict(degree=1, control_points=[(0, 0), (1, 0), (2, 0)], knots=[0, 0, 0, 1, 1]), "knots", "repeats an end knot"),
        (dict(degree=1, control_points=[(0, 0), (1, 0), (2, 0)], knots=[0, 0, 1, 1, 1]), "knots", "repeats an end knot"),
        (dict(degree=1, control_points=[(0, 0), (1, 0)], weights=[1, 1e-300]), "weights", "must lie in"),
    ],
)
def test_invalid_definitions_name_the_field(kwargs, field, fragment):
    with pytest.raises(CurveError) as info:
        NurbsCurve.create(**kwargs)
    assert info.value.field == field
    assert fragment in str(info.value)


@given(random_curves(), st.integers(0, 3), st.integers(1, 5000))
@settings(max_examples=40, deadline=None)
def test_derivatives_by_coordinate_are_derivatives_transposed(curve, order, count):
    """The planner's coordinate-major evaluation gives derivatives()' numbers, also across
    evaluation chunks (counts above EVALUATION_CHUNK)."""
    u = np.linspace(curve.u_min, curve.u_max, count)
    rows = curve.derivatives(u, order)
    by_coordinate = curve.derivatives_by_coordinate(u, order)
    assert len(by_coordinate) == order + 1
    for k in range(order + 1):
        assert by_coordinate[k].shape == (curve.dim, count)
        assert np.array_equal(by_coordinate[k].T, rows[k])
