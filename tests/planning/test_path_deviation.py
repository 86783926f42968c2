"""path_deviation: exact distances to lines and arcs, sampled NURBS, and the grid search
against brute force (dense sampling of the same curves)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve, line_curve
from nurbsmotion.planning.path_deviation import (brute_distances, circle_span, distances_to_path, max_deviation_mm,
                                                 path_elements, program_path)
from nurbsmotion.program import parse_gcode


def dense_points(curves, per_curve: int = 20001) -> np.ndarray:
    return np.vstack([c.points(np.linspace(c.u_min, c.u_max, per_curve)) for c in curves])


def sampled_distances(points: np.ndarray, curves, per_curve: int = 20001) -> np.ndarray:
    """Brute force: nearest of the dense points of each curve (overestimates by at most the half spacing)."""
    return cKDTree(dense_points(curves, per_curve)).query(points)[0]


def test_segment_distance_is_exact():
    path = path_elements([line_curve((0, 0, 0), (10, 0, 0))])
    points = np.array([[5, 3, 4], [-3, 4, 0], [13, 0, 4], [2, 0, 0]], dtype=float)
    assert distances_to_path(points, path) == pytest.approx([5.0, 5.0, 5.0, 0.0], abs=1e-12)


def test_arc_is_recognised_as_circle_with_its_centre_radius_and_sweep():
    curve = arc_curve((1, 2, 3), (6, 2, 3), math.radians(250))
    path = path_elements([curve])
    assert path.segment_count == 0 and path.arc_count == 3
    assert path.arc_center == pytest.approx(np.tile([1, 2, 3], (3, 1)))
    assert path.arc_radius == pytest.approx([5, 5, 5])
    assert path.arc_sweep_rad.sum() == pytest.approx(math.radians(250))
    assert path.arc_end[-1] == pytest.approx(curve.end_point)


def test_arc_distance_is_exact_inside_and_beyond_the_sweep():
    path = path_elements([arc_curve((0, 0, 0), (10, 0, 0), math.pi / 2)])  # quarter circle, first quadrant
    points = np.array([[0, 0, 0], [14, 14, 0], [3, 3, 0], [7.0710678, 7.0710678, 2.0], [0, -10, 0], [-10, 0, 0]])
    r = np.hypot(14, 14)
    expected = [10.0, r - 10, 10 - math.hypot(3, 3), 2.0, math.hypot(10, 10), math.hypot(10, 10)]
    assert distances_to_path(points, path) == pytest.approx(expected, abs=1e-6)


def test_helix_and_nurbs_are_sampled_within_the_tolerance():
    helix = arc_curve((0, 0, 0), (5, 0, 0), 3 * math.pi, rise_mm=4.0)
    nurbs = NurbsCurve.create(3, [[0, 0, 0], [5, 10, 0], [10, -10, 1], [15, 0, 0], [20, 5, 2]])
    curves = [helix, nurbs]
    path = path_elements(curves, sample_tolerance_mm=1e-4)
    assert path.arc_count == 0
    rng = np.random.default_rng(2)
    points = np.vstack([dense_points(curves, 50)[::3] + rng.normal(0, 0.3, (34, 3)),
                        rng.uniform(-8, 22, (60, 3))])
    ours = distances_to_path(points, path)
    theirs = sampled_distances(points, curves)
    # the polyline is within the tolerance of the curve; the dense points overestimate by at most half their spacing
    assert np.all(ours <= theirs + 1e-4 + 1e-12)
    assert np.all(ours >= theirs - 1.5e-3 - 1e-4)


def test_non_circular_rational_quadratic_is_not_taken_for_a_circle():
    p = np.array([[0.0, 0, 0], [1, 1, 0], [2, 0, 0]])
    assert circle_span(p[0], p[1], p[2], math.cos(math.pi / 4)) is not None
    assert circle_span(p[0], p[1], p[2], 0.5) is None
    assert circle_span(p[0], np.array([1.0, 1, 1]), p[2], math.cos(math.pi / 4)) is None


@pytest.mark.parametrize("cell_mm", [0.05, 1.0, 7.0])
def test_grid_search_equals_brute_force_on_a_mixed_path(cell_mm):
    rng = np.random.default_rng(7)
    corners = np.cumsum(rng.normal(0, 3, (40, 3)), axis=0)
    curves = [line_curve(a, b) for a, b in zip(corners[:-1], corners[1:])]
    curves += [arc_curve(c, c + (r, 0, 0), s, normal=n) for c, r, s, n in
               zip(rng.normal(0, 10, (15, 3)), rng.uniform(0.5, 6, 15), rng.uniform(-6, 6, 15), rng.normal(0, 1, (15, 3)))]
    path = path_elements(curves)
    near = dense_points(curves, 40) + rng.normal(0, 0.2, (len(curves) * 40, 3))
    points = np.vstack([near, rng.uniform(-40, 40, (300, 3))])
    assert distances_to_path(points, path, cell_mm) == pytest.approx(brute_distances(points, path), abs=1e-12)
    assert brute_distances(points, path) == pytest.approx(sampled_distances(points, curves, 8001), abs=5e-3)


def test_program_path_covers_rapids_lines_and_arcs_in_machine_coordinates():
    program = parse_gcode("G21 G90 G54\nG10 L2 P1 X100\nG0 X10 Y0\nG1 X20 F600\nG2 X30 Y0 I5 J0\nM2\n", "t.ngc")
    path = program_path(program)
    assert path.arc_count == 2 and path.segment_count == 2
    assert max_deviation_mm([[115, 0, 0], [125, 5, 0], [125, 40, 0], [50, 0, 0]], program) == pytest.approx(35.0)
    assert distances_to_path([[125, 7, 0]], path)[0] == pytest.approx(2.0)


def test_empty_inputs():
    path = path_elements([line_curve((0, 0, 0), (1, 0, 0))])
    assert len(distances_to_path(np.zeros((0, 3)), path)) == 0
    assert np.isinf(distances_to_path([[0, 0, 0]], path_elements([]))).all()
