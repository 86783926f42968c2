"""Short-segment smoothing (geometry/polyline_fit.py): runs, fits within the tolerance both
ways (checked by a brute-force ruler written here, not the module's own ``max_deviation``),
G2 ends, fewer control points, sharp corners kept, degenerate input, real CAM programs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.polyline_fit import (FitError, curvature_report, fit_run, max_deviation, runs_forward,
                                               smooth_polyline, smoothable_runs)
from nurbsmotion.program import read_program
from nurbsmotion.program.line_chains import line_chains
from tests.planning.lookahead.test_no_give_ups import braid_program

GCODE = Path(__file__).resolve().parents[1] / "data" / "gcode"
TOLERANCE_MM = 0.01
RULER_STEP_MM = 0.01  # coarse curve samples of the ruler at most this far apart (arc length)
RULER_FINE = 50  # fine samples in each refined interval
RULER_WINDOW = 4  # refined samples are measured against the segments this far from the nearest one


# ---- the independent ruler ---------------------------------------------------------------

def _point_segment_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|p_i - segment_j| for every pair: shape (len(p), len(a))."""
    ab = b - a
    len2 = np.maximum((ab * ab).sum(axis=1), 1e-300)
    rel = p[:, None, :] - a[None, :, :]
    t = np.clip((rel * ab[None]).sum(axis=2) / len2, 0.0, 1.0)
    return np.linalg.norm(rel - t[:, :, None] * ab[None], axis=2)


def _point_segment_distances_rows(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|p_ij - segment_i| for points p (k, m, 3) and one segment (a_i, b_i) per row: shape (k, m)."""
    ab = (b - a)[:, None, :]
    rel = p - a[:, None, :]
    t = np.clip((rel * ab).sum(axis=2) / np.maximum((ab * ab).sum(axis=2), 1e-300), 0.0, 1.0)
    return np.linalg.norm(rel - t[:, :, None] * ab, axis=2)


def _nearest(p: np.ndarray, a: np.ndarray, b: np.ndarray, chunk: int = 400_000) -> tuple[np.ndarray, np.ndarray]:
    """(distance, index) of the nearest segment of all, for each point."""
    rows = max(1, chunk // max(len(a), 1))
    parts = [_point_segment_distances(p[i:i + rows], a, b) for i in range(0, len(p), rows)]
    return np.concatenate([d.min(axis=1) for d in parts]), np.concatenate([d.argmin(axis=1) for d in parts])


def _samples(curve: NurbsCurve, lo: np.ndarray, hi: np.ndarray, n: int) -> tuple[np.ndarray, float]:
    """Curve points at n + 1 even u in each [lo, hi], and a bound on the arc length between
    neighbours (the largest speed seen, times 1.05, times the u step)."""
    u = (lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, n + 1)).ravel()
    x, d1 = curve.derivatives(u, 1)
    return x, 1.05 * float(np.linalg.norm(d1, axis=1).max()) * float((hi - lo).max()) / n


def ruler(curve: NurbsCurve, points: np.ndarray) -> float:
    """Brute force, both ways, as an upper bound. Vertex to curve: the nearest of all coarse
    curve samples, then of RULER_FINE samples over the two steps around it (any curve point
    bounds the distance from above). Curve to polyline: every coarse sample to every segment;
    the distance moves at most as fast as arc length, so a sample whose distance + step / 2 may
    pass the tolerance has its two steps resampled finely and bounded the same way (against the
    segments around its nearest: fewer segments can only make the bound larger)."""
    n = max(2000, int(curve.length / RULER_STEP_MM) + 1)
    edges = np.linspace(curve.u_min, curve.u_max, n + 1)
    x, step = _samples(curve, edges[:1], edges[-1:], n)
    near = np.concatenate([_point_segment_distances(points[i:i + 1], x[:-1], x[1:]).argmin(axis=1)
                           for i in range(len(points))])
    fine, _ = _samples(curve, edges[np.maximum(near - 1, 0)], edges[np.minimum(near + 2, n)], RULER_FINE)
    fine = fine.reshape(len(points), RULER_FINE + 1, -1)
    vertex_to_curve = float(np.linalg.norm(fine - points[:, None, :], axis=2).min(axis=1).max())
    coarse, nearest = _nearest(x, points[:-1], points[1:])
    bound = coarse + step / 2.0
    doubtful = np.flatnonzero(bound > TOLERANCE_MM)
    if len(doubtful):
        x_fine, fine_step = _samples(curve, edges[np.maximum(doubtful - 1, 0)], edges[np.minimum(doubtful + 1, n)],
                                     RULER_FINE)
        x_fine = x_fine.reshape(len(doubtful), RULER_FINE + 1, -1)
        # the segments around the brute-force nearest one: a subset, so still an upper bound
        window = np.clip(nearest[doubtful][:, None] + np.arange(-RULER_WINDOW, RULER_WINDOW + 1), 0, len(points) - 2)
        d = np.stack([_point_segment_distances_rows(x_fine, points[window[:, k]], points[window[:, k] + 1])
                      for k in range(window.shape[1])]).min(axis=0)
        bound[doubtful] = d.max(axis=1) + fine_step / 2.0
    return max(vertex_to_curve, float(bound.max()))


def assert_g2_ends(curve: NurbsCurve, points: np.ndarray) -> None:
    """Exactly at the end vertices, unit tangent along the end segments, curvature 0 there."""
    np.testing.assert_array_equal(curve.derivatives(curve.u_min, 0)[0], points[0])
    np.testing.assert_allclose(curve.derivatives(curve.u_max, 0)[0], points[-1], atol=1e-12)
    d_start = curve.derivatives(curve.u_min, 1)[1]
    d_end = curve.derivatives(curve.u_max, 1)[1]
    first, last = points[1] - points[0], points[-1] - points[-2]
    np.testing.assert_allclose(d_start / np.linalg.norm(d_start), first / np.linalg.norm(first), atol=1e-9)
    np.testing.assert_allclose(d_end / np.linalg.norm(d_end), last / np.linalg.norm(last), atol=1e-9)
    assert curve.curvature(curve.u_min) < 1e-9 and curve.curvature(curve.u_max) < 1e-9


# ---- synthetic ------------------------------------------------------------------------------

def noisy(points: np.ndarray, amplitude_mm: float, seed: int) -> np.ndarray:
    """Interior vertices moved by up to ``amplitude_mm`` per coordinate (CAM rounding)."""
    out = points.copy()
    out[1:-1] += np.random.default_rng(seed).uniform(-amplitude_mm, amplitude_mm, out[1:-1].shape)
    return out


def circle_chords(radius_mm: float, sweep_rad: float, n: int) -> np.ndarray:
    a = np.linspace(0.0, sweep_rad, n)
    return np.column_stack([radius_mm * np.cos(a), radius_mm * np.sin(a), np.zeros(n)])


def sine_chords(n: int) -> np.ndarray:
    x = np.linspace(0.0, 60.0, n)
    return np.column_stack([x, 5.0 * np.sin(x / 6.0), 0.02 * x])


@pytest.mark.parametrize("name, points", [
    ("circle r=20, 270 deg, 0.3 mm chords", noisy(circle_chords(20.0, 1.5 * math.pi, 300), 0.003, 1)),
    ("circle r=2, 360 deg, 0.1 mm chords", noisy(circle_chords(2.0, 2 * math.pi, 126), 0.002, 2)),
    ("helical sine, 0.2 mm chords", noisy(sine_chords(400), 0.003, 3)),
])
def test_a_sampled_smooth_curve_fits_within_tolerance_with_few_control_points(name, points):
    curve = fit_run(points, TOLERANCE_MM)
    assert ruler(curve, points) <= TOLERANCE_MM, name
    assert max_deviation(curve, points).max_mm <= TOLERANCE_MM
    assert len(curve.control_points) <= len(points) / 5, name
    assert_g2_ends(curve, points)
    assert runs_forward(curve, points)


def test_max_deviation_sees_a_curve_that_leaves_the_polyline():
    """The module's ruler against a known offset: the circle's own chords vs a circle 0.05 mm out."""
    points = circle_chords(20.0, 1.0, 50)
    curve = fit_run(points, TOLERANCE_MM)
    shifted = NurbsCurve.create(3, curve.control_points * (20.05 / 20.0), None, curve.knots)
    deviation = max_deviation(shifted, points)
    assert 0.04 < deviation.vertex_to_curve_mm < 0.06 and 0.04 < deviation.curve_to_polyline_mm < 0.06


def test_the_fit_is_gentler_than_the_polyline():
    """Noise below the tolerance is averaged, not followed: the fit's curvature stays near the
    circle's while the polyline's discrete curvature jumps with the noise."""
    points = noisy(circle_chords(20.0, 1.5 * math.pi, 300), 0.003, 1)
    report = curvature_report(fit_run(points, TOLERANCE_MM), points)
    assert report.curve_per_mm < 2.0 / 20.0 < report.polyline_per_mm


# ---- runs --------------------------------------------------------------------------------------

def square_of_short_segments(side_mm: float = 10.0, per_side: int = 20) -> np.ndarray:
    corners = np.array([(0, 0, 0), (side_mm, 0, 0), (side_mm, side_mm, 0), (0, side_mm, 0), (0, 0, 0)], float)
    t = np.arange(per_side) / per_side
    sides = [a + np.outer(t, b - a) for a, b in zip(corners[:-1], corners[1:])]
    return np.vstack(sides + [corners[-1:]])


def test_a_square_keeps_its_four_corners():
    points = square_of_short_segments()
    runs = smoothable_runs(points)
    assert [(r.first, r.last) for r in runs] == [(0, 20), (20, 40), (40, 60), (60, 80)]
    for run in runs:
        vertices = run.vertices(points)
        curve = fit_run(vertices, TOLERANCE_MM)
        assert ruler(curve, vertices) <= TOLERANCE_MM
        assert np.max(curve.curvature(np.linspace(curve.u_min, curve.u_max, 100))) < 1e-9  # straight sides


def test_long_segments_feed_changes_and_breaks_end_runs():
    points = circle_chords(20.0, 1.0, 41)  # 40 chords of 0.5 mm
    assert [(r.first, r.last) for r in smoothable_runs(points)] == [(0, 40)]
    assert smoothable_runs(points, max_segment_mm=0.4) == []
    feeds = np.full(40, 10.0)
    feeds[20:] = 20.0
    assert [(r.first, r.last) for r in smoothable_runs(points, feeds)] == [(0, 20), (20, 40)]
    breaks = np.zeros(41, bool)
    breaks[10] = True
    assert [(r.first, r.last) for r in smoothable_runs(points, breaks=breaks)] == [(0, 10), (10, 40)]
    assert [(r.first, r.last) for r in smoothable_runs(points, min_segments=41)] == []
    runs = smoothable_runs(points, max_run_segments=15)
    assert runs[0].first == 0 and runs[-1].last == 40 and all(r.segments <= 15 for r in runs)
    assert all(a.last == b.first for a, b in zip(runs, runs[1:]))


def test_a_vertex_sharper_than_the_corner_angle_ends_the_run():
    """An L of 0.5 mm segments: its 90 deg vertex is a corner unless corner_deg is above 90."""
    points = np.vstack([np.column_stack([np.linspace(-5, 0, 11), np.zeros(11), np.zeros(11)]),
                        np.column_stack([np.zeros(10), np.linspace(0.5, 5, 10), np.zeros(10)])])
    assert [(r.first, r.last) for r in smoothable_runs(points, corner_deg=30)] == [(0, 10), (10, 20)]
    assert [(r.first, r.last) for r in smoothable_runs(points, corner_deg=91)] == [(0, 20)]


def test_a_polygon_coarse_for_the_tolerance_is_no_run():
    """A 16-gon of radius 10 (3.9 mm chords turning 22.5 deg) bulges 0.19 mm from its chords as a
    smooth curve: at 0.01 mm it is a polygon, at 0.5 mm a sampled circle."""
    points = circle_chords(10.0, 2 * math.pi, 17)
    assert smoothable_runs(points, tolerance_mm=TOLERANCE_MM) == []
    assert [(r.first, r.last) for r in smoothable_runs(points, tolerance_mm=0.5)] == [(0, 16)]
    with pytest.raises(FitError, match="no cubic within 0.01 mm of this run of 17 vertices with at most 25"):
        fit_run(points, TOLERANCE_MM)


def test_a_run_no_fit_simplifies_is_kept_as_lines():
    """A zigzag of 0.2 mm steps +-15 um across: gentle (17 deg) and fine enough for the coarse
    rule, but any curve within 10 um of it must wiggle at every vertex."""
    n = 40
    points = np.column_stack([np.arange(n) * 0.2, np.where(np.arange(n) % 2, 0.015, -0.015), np.zeros(n)])
    points[0, 1] = points[-1, 1] = 0.0
    result = smooth_polyline(points, TOLERANCE_MM)
    assert result.fitted == [] and [(r.first, r.last) for r in result.kept] == [(0, n - 1)]
    circle = circle_chords(20.0, 1.0, 41)
    result = smooth_polyline(circle, TOLERANCE_MM)
    assert [(f.span.first, f.span.last) for f in result.fitted] == [(0, 40)] and result.kept == []


# ---- degenerate input -----------------------------------------------------------------------

def test_two_points_and_collinear_runs_are_straight_cubics():
    for points in (np.array([[0, 0, 0], [1, 2, 3]], float), np.outer(np.linspace(0, 1, 7), [3.0, 4.0, 0.0])):
        curve = fit_run(points, TOLERANCE_MM)
        assert curve.degree == 3 and ruler(curve, points) <= TOLERANCE_MM
        assert np.max(curve.curvature(np.linspace(curve.u_min, curve.u_max, 50))) < 1e-9
        assert_g2_ends(curve, points)


def test_repeated_points_are_one_vertex():
    points = noisy(circle_chords(5.0, 2.0, 60), 0.002, 4)
    repeated = np.vstack([points[:1], points[:30], points[29:30], points[29:], points[-1:]])
    curve = fit_run(repeated, TOLERANCE_MM)
    assert ruler(curve, points) <= TOLERANCE_MM
    assert_g2_ends(curve, points)
    assert [(r.first, r.last) for r in smoothable_runs(repeated)] == [(0, len(repeated) - 1)]


@pytest.mark.parametrize("points, tolerance, message", [
    ([[1, 1, 1], [1, 1, 1], [1, 1, 1]], 0.01, "points: a run needs two distinct vertices"),
    ([[0, 0, 0], [1, float("nan"), 0], [2, 0, 0]], 0.01, "points: vertex 1 is not a finite point"),
    ([1, 2, 3], 0.01, "points: must be a list of points"),
    ([[0, 0, 0], [1, 0, 0]], 0.0, "tolerance_mm: must be a number > 0, got 0.0"),
])
def test_bad_input_is_one_error_line(points, tolerance, message):
    with pytest.raises(FitError) as err:
        fit_run(points, tolerance)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_tiny_inputs_have_no_runs():
    assert smoothable_runs(np.zeros((1, 3))) == []
    assert smoothable_runs(np.array([[0, 0, 0], [1, 0, 0]], float)) == []


# ---- real CAM programs ------------------------------------------------------------------------

CAM_PROGRAMS = ["grbl_HSM_test.nc", "braid_cut2d.nc", "fusion360_led_floor_1071_surface_40mm_10overlap.nc"]


def cam_program(name: str):
    """braid_cut2d.nc with test_no_give_ups' two-line adaptation; the others as published."""
    return braid_program() if name == "braid_cut2d.nc" else read_program(GCODE / name)


@pytest.mark.slow
@pytest.mark.parametrize("name", CAM_PROGRAMS)
def test_real_cam_programs_fit_every_run_within_tolerance(name, capsys):
    program = cam_program(name)
    vertices = runs = control_points = run_vertices = kept = 0
    measured = kappa_curve = kappa_polyline = 0.0
    for chain in line_chains(program):
        vertices += len(chain.points)
        result = smooth_polyline(chain.points, TOLERANCE_MM, chain.feeds_mm_s, chain.breaks)
        kept += len(result.kept)
        for fit in result.fitted:
            points = fit.span.vertices(chain.points)
            measured = max(measured, max_deviation(fit.curve, points).max_mm)
            report = curvature_report(fit.curve, points)
            kappa_curve, kappa_polyline = max(kappa_curve, report.curve_per_mm), max(kappa_polyline, report.polyline_per_mm)
            assert ruler(fit.curve, points) <= TOLERANCE_MM, (name, fit.span)
            assert_g2_ends(fit.curve, points)
            assert runs_forward(fit.curve, points), (name, fit.span)
            runs += 1
            run_vertices += len(points)
            control_points += len(fit.curve.control_points)
    with capsys.disabled():
        print(f"\n{name}: {vertices} vertices, {runs} runs of {run_vertices} vertices -> {control_points} control "
              f"points ({kept} runs kept as lines), largest deviation {measured * 1000:.2f} um (max_deviation), "
              f"every run within {TOLERANCE_MM * 1000:g} um by the ruler; largest curvature {kappa_curve:.2f}/mm "
              f"(the polylines' discrete curvature: up to {kappa_polyline:.2f}/mm)")
    if runs + kept == 0:  # nothing to smooth must mean no three short segments in a row at all
        short = np.concatenate([np.linalg.norm(np.diff(c.points, axis=0), axis=1) < 5.0 for c in line_chains(program)])
        assert not np.any(short[:-2] & short[1:-1] & short[2:])
    else:
        assert control_points < run_vertices / 3 and kept < runs
