"""Property tests: any valid NURBS written as G06.2 reads back unchanged; any arc ends exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nurbsmotion.program import parse_gcode
from nurbsmotion.program.arcs import PLANES
from nurbsmotion.program.summary import curve_samples


@st.composite
def nurbs_definitions(draw):
    degree = draw(st.integers(1, 3))
    n = draw(st.integers(degree + 1, degree + 8))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    points = rng.uniform(-150, 150, (n, 3))
    weights = rng.uniform(0.1, 10, n)
    inner = np.sort(rng.uniform(0, 1, n - degree - 1))
    u0, width = draw(st.floats(-5, 5)), draw(st.floats(0.01, 100))
    knots = u0 + width * np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])
    return degree, points, weights, knots


def g06_2_text(degree, points, weights, knots, feed=1000.0) -> str:
    points, weights, knots = points.tolist(), weights.tolist(), knots.tolist()  # Python floats: repr round-trips
    lines = []
    for i, (p, w, k) in enumerate(zip(points, weights, knots)):
        head = f"G06.2 P{degree + 1} " if i == 0 else ""
        tail = f" F{feed!r}" if i == 0 else ""
        lines.append(f"{head}K{k!r} X{p[0]!r} Y{p[1]!r} Z{p[2]!r} R{w!r}{tail}")
    lines += [f"K{k!r}" for k in knots[len(points):]]
    return "\n".join(lines)


@settings(max_examples=60, deadline=None)
@given(nurbs_definitions())
def test_any_valid_nurbs_reads_back_unchanged_from_g06_2(definition):
    degree, points, weights, knots = definition
    program = parse_gcode(g06_2_text(degree, points, weights, knots), "p.nc", points[0])
    (block,) = program.blocks
    assert block.curve.degree == degree
    np.testing.assert_array_equal(block.curve.control_points, points)
    np.testing.assert_array_equal(block.curve.weights, weights)
    np.testing.assert_array_equal(block.curve.knots, knots)


def circumcentre(p1, p2, p3, a: int, b: int) -> np.ndarray:
    """Centre of the circle through three points, in the plane of axes a and b."""
    (ax, ay), (bx, by), (cx, cy) = p1[[a, b]], p2[[a, b]], p3[[a, b]]
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    ux = ((ax**2 + ay**2) * (by - cy) + (bx**2 + by**2) * (cy - ay) + (cx**2 + cy**2) * (ay - by)) / d
    uy = ((ax**2 + ay**2) * (cx - bx) + (bx**2 + by**2) * (ax - cx) + (cx**2 + cy**2) * (bx - ax)) / d
    centre = p1.copy()
    centre[a], centre[b] = ux, uy
    return centre


@settings(max_examples=80, deadline=None)
@given(plane=st.sampled_from([17, 18, 19]), radius=st.floats(1, 100),
       start_angle=st.floats(-math.pi, math.pi),
       sweep=st.floats(-2 * math.pi + 1e-3, 2 * math.pi - 1e-3).filter(lambda s: abs(s) > 1e-3),
       origin=st.tuples(*[st.floats(-50, 50)] * 3))
def test_any_ijk_arc_ends_exactly_at_the_programmed_point_on_its_circle(plane, radius, start_angle, sweep, origin):
    p = PLANES[plane]
    a, b = p.axes
    centre = np.array(origin)
    start, end = centre.copy(), centre.copy()
    start[a] += radius * math.cos(start_angle)
    start[b] += radius * math.sin(start_angle)
    end[a] += radius * math.cos(start_angle + sweep)
    end[b] += radius * math.sin(start_angle + sweep)
    end[[a, b]] = np.round(end[[a, b]], 6)  # as a CAM post-processor would write it
    offset = centre - start
    words = " ".join(f"{'XYZ'[i]}{float(end[i])!r}" for i in (a, b))
    ijk = " ".join(f"{'IJK'[i]}{float(offset[i])!r}" for i in (a, b))
    text = f"G{plane} G0{2 if sweep < 0 else 3} {words} {ijk} F600"
    (block,) = parse_gcode(text, "arc.nc", start).blocks
    np.testing.assert_array_equal(block.start, start)
    np.testing.assert_array_equal(block.end, end)
    # writing the end with 6 decimals moves it up to 5e-7 mm off the circle; the reader then
    # shifts the centre onto the chord's bisector, most for arcs close to a full turn
    pts = curve_samples(block.curve)
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=1), radius, atol=1e-3)
    own_centre = circumcentre(pts[0], pts[len(pts) // 3], pts[2 * len(pts) // 3], a, b)
    own = np.linalg.norm(pts - own_centre, axis=1)
    np.testing.assert_allclose(own, own[0], atol=1e-9 * max(1.0, radius))  # still an exact circle
    np.testing.assert_allclose(pts[:, p.normal_axis], start[p.normal_axis])  # in the plane
    assert block.length_mm == pytest.approx(abs(sweep) * radius, abs=1e-3)
