"""Corner blending in the look-ahead (planning/lookahead/blend.py): corners within the path
tolerance are passed moving on G2 blends, every limit holds on every set-point, and the
program's own stops still stop. The rulers: planning.measure against the planned pieces
(conftest.measure_planned) and the brute-force distance of every set-point from the
program's blocks (conftest.path_deviation_mm)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead, planned_pieces
from nurbsmotion.planning.lookahead import blend
from nurbsmotion.planning.lookahead.blend import MAX_DEFLECTION_DEG
from nurbsmotion.program import parse_gcode
from tests.planning.lookahead.conftest import assert_within_limits, measure_planned, path_deviation_mm, polyline

LIMITS = PlanLimits(period_s=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0, default_feed_mm_s=200.0,
                    path_tolerance_mm=0.01)
NO_JERK = replace(LIMITS, max_jerk_mm_s3=None)
DATA = Path(__file__).resolve().parents[2] / "data" / "gcode"


def turn(theta_deg: float, length: float = 20.0) -> list[tuple[float, float, float]]:
    th = np.radians(theta_deg)
    return [(0.0, 0.0, 0.0), (length, 0.0, 0.0), (length + length * np.cos(th), length * np.sin(th), 0.0)]


def speed_near(trajectory, point) -> float:
    """Speed (mm/s) of the step that passes closest to ``point``."""
    i = int(np.argmin(np.linalg.norm(trajectory.position_mm - np.asarray(point), axis=1)))
    i = min(max(i, 1), len(trajectory.u) - 1)
    return float(np.linalg.norm(trajectory.position_mm[i] - trajectory.position_mm[i - 1]) / trajectory.period_s)


def assert_blended_plan_holds(trajectory, program, limits) -> None:
    assert_within_limits(measure_planned(trajectory, program, limits), limits)
    deviation = path_deviation_mm(trajectory, program)
    assert deviation <= limits.path_tolerance_mm
    assert trajectory.notes["verified_max_path_deviation_mm"] == pytest.approx(deviation, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
@pytest.mark.parametrize("theta_deg", [5.0, 15.0, MAX_DEFLECTION_DEG])
def test_a_corner_is_passed_moving_on_a_blend_within_the_tolerance(theta_deg, limits):
    program = polyline(turn(theta_deg))
    trajectory = plan_lookahead(program, limits)
    assert trajectory.notes["stops"] == 0
    corner = turn(theta_deg)[1]
    assert speed_near(trajectory, corner) > 0.1
    assert not np.any(np.all(trajectory.position_mm == corner, axis=1))  # the corner itself is cut
    assert_blended_plan_holds(trajectory, program, limits)
    blend = next(p for p in planned_pieces(program, limits) if p.corners is not None)
    on_blend = replace_rows(trajectory, np.ones(len(trajectory.u), dtype=bool))
    on_blend.position_mm = blend.curve.points(np.linspace(0.0, 1.0, 4001))
    if theta_deg >= 15.0:  # not cut short by the 20 mm lines: the blend uses its tolerance
        assert path_deviation_mm(on_blend, program) >= 0.95 * limits.path_tolerance_mm


def g2_joins(pieces) -> list[float]:
    """Relative difference of the curvature vectors (and of the unit tangents) at every join."""
    out = []
    for a, b in zip(pieces[:-1], pieces[1:]):
        ends = []
        for piece, u in ((a, a.u_end), (b, b.u_start)):
            x, d1, d2 = piece.curve.derivatives(u, 2)
            speed = np.linalg.norm(d1)
            t = d1 / speed
            ends.append((x, t, (d2 - (d2 @ t) * t) / speed**2))
        (xa, ta, ka), (xb, tb, kb) = ends
        assert np.linalg.norm(xa - xb) <= 1e-9
        scale = max(np.linalg.norm(ka), np.linalg.norm(kb), 1.0)
        out.append(max(np.linalg.norm(ta - tb), np.linalg.norm(ka - kb) / scale))
    return out


@pytest.fixture
def blend_to_60_deg(monkeypatch):
    """Corners up to 60 deg blended (the planner's own limit is a policy: MAX_DEFLECTION_DEG)."""
    monkeypatch.setattr(blend, "MAX_DEFLECTION_DEG", 60.0)


def test_line_arc_and_arc_arc_corners_are_blended_g2_and_hold_every_limit(blend_to_60_deg):
    # 45 deg each: line-arc, arc-arc, arc-line, line-line
    text = "G1 X20 F6000\nG3 X30 Y0 I5 J5\nG2 X40 Y0 I5 J0\nG1 X50 Y-10\nX70\n"
    program = parse_gcode(text, "arcs.nc")
    pieces = planned_pieces(program, LIMITS)
    blends = [p for p in pieces if p.corners is not None]
    assert len(blends) == 4
    assert max(g2_joins(pieces)) <= 1e-9
    for limits in (LIMITS, NO_JERK):
        trajectory = plan_lookahead(program, limits)
        assert trajectory.notes["stops"] == 0
        assert_blended_plan_holds(trajectory, program, limits)


def test_a_blend_takes_at_most_half_of_each_neighbour(blend_to_60_deg):
    """Short segments (0.054 mm) with 44 deg corners: every blend is cut short by the segments
    (its ends at most half a segment from the corner; two blends may meet at a middle, the
    segment then keeps no piece of its own), and every block is still on the path."""
    points = [(0.05 * i, 0.02 * (i % 2), 0.0) for i in range(12)]  # corners of 43.6 deg
    program = polyline(points)
    pieces = planned_pieces(program, LIMITS)
    for piece in pieces:
        if piece.corners is None:
            continue
        start, end = piece.curve.points(np.array([0.0, 1.0]))
        inc, out = piece.corners.incoming, piece.corners.outgoing
        k = piece.corner
        assert (start - inc.start[k]) @ inc.direction[k] >= 0.5 * inc.length_mm[k] - 1e-12
        assert (end - out.start[k]) @ out.direction[k] <= 0.5 * out.length_mm[k] + 1e-12
    assert {p.block for p in pieces} == set(range(len(program.blocks)))
    trajectory = plan_lookahead(program, LIMITS)
    assert_blended_plan_holds(trajectory, program, LIMITS)


def rests_at(trajectory, point) -> bool:
    """Two consecutive set-points exactly at ``point`` (the stop's corner, held a cycle)."""
    at = np.flatnonzero(np.all(trajectory.position_mm == np.asarray(point, float), axis=1))
    return len(at) >= 2 and bool(np.any(np.diff(at) == 1))


@pytest.mark.parametrize("stop", ["G61", "G4 P0.01", "M0", "T2 M6"])
def test_program_stops_still_stop_at_the_corner(stop, blend_to_60_deg):
    line = {"G61": "G61 X20\nG64", "G4 P0.01": "X20\nG4 P0.01", "M0": "X20\nM0", "T2 M6": "X20\nT2 M6"}[stop]
    program = parse_gcode(f"G1 X10 F6000\n{line}\nX30 Y10\nX50\n", "stops.nc")  # G61 is modal: G64 after it
    trajectory = plan_lookahead(program, LIMITS)
    assert rests_at(trajectory, (20.0, 0.0, 0.0))
    assert not rests_at(trajectory, (30.0, 10.0, 0.0))  # the 45 deg corner after it is blended
    assert_blended_plan_holds(trajectory, program, LIMITS)


def test_a_corner_sharper_than_the_blend_limit_stays_a_stop():
    program = polyline(turn(MAX_DEFLECTION_DEG + 10.0))
    assert not any(p.corners is not None for p in planned_pieces(program, LIMITS))
    trajectory = plan_lookahead(program, LIMITS)
    assert rests_at(trajectory, turn(MAX_DEFLECTION_DEG + 10.0)[1])


def test_a_zero_path_tolerance_keeps_the_corners_as_junctions():
    program = polyline(turn(30.0))
    assert not any(p.corners is not None for p in planned_pieces(program, replace(LIMITS, path_tolerance_mm=0.0)))


def test_g64_p_sets_the_tolerance_of_the_corner_into_its_block(blend_to_60_deg):
    program = parse_gcode("G1 X20 F6000\nG64 P0.002\nX40 Y20\nG64 P0.02\nX60\n", "p.nc")  # 45 deg corners
    trajectory = plan_lookahead(program, LIMITS)
    near_first = np.linalg.norm(trajectory.position_mm - [20.0, 0.0, 0.0], axis=1) < 1.0
    first = polyline([(0, 0, 0), (20, 0, 0), (40, 20, 0)])
    assert path_deviation_mm(replace_rows(trajectory, near_first), first) <= 0.002
    assert trajectory.notes["verified_max_path_deviation_mm"] > 0.01  # the second corner uses its 0.02


def replace_rows(trajectory, rows):
    from nurbsmotion.planning import Trajectory
    return Trajectory(trajectory.algorithm, trajectory.period_s, trajectory.block[rows], trajectory.u[rows],
                      trajectory.position_mm[rows], trajectory.feed_mm_s[rows])


def zigzag(n: int = 60, step: float = 0.5) -> list[tuple[float, float, float]]:
    """Short segments turning 20 deg either way: a CAM-like polyline."""
    points, heading, p = [(0.0, 0.0, 0.0)], 0.0, np.zeros(3)
    for i in range(n):
        heading += np.radians(20.0) * (1 if (i // 3) % 2 == 0 else -1)
        p = p + step * np.array([np.cos(heading), np.sin(heading), 0.0])
        points.append(tuple(p))
    return points


def test_motion_time_falls_as_the_jerk_limit_grows():
    program = polyline(zigzag())
    times = [len(plan_lookahead(program, replace(LIMITS, max_jerk_mm_s3=j)).u) for j in (5e4, 5e5, 5e6, 1e12, None)]
    assert all(a >= b for a, b in zip(times[:-1], times[1:])), times
    assert times[-2] <= 1.05 * times[-1]  # an unlimited jerk plans like no jerk limit


def test_a_short_segment_program_holds_every_limit_and_the_tolerance():
    program = polyline(zigzag())
    for limits in (LIMITS, NO_JERK):
        trajectory = plan_lookahead(program, limits)
        assert trajectory.notes["stops"] == 0
        assert_blended_plan_holds(trajectory, program, limits)


def cam_head(path: Path, lines: int) -> str:
    return "\n".join(path.read_text().splitlines()[:lines]) + "\n"


@pytest.mark.slow
@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_the_first_lines_of_grbl_hsm_test_hold_every_limit_and_the_tolerance(limits):
    program = parse_gcode(cam_head(DATA / "grbl_HSM_test.nc", 300), "grbl_HSM_test.nc")
    trajectory = plan_lookahead(program, limits)
    assert_blended_plan_holds(trajectory, program, limits)


@pytest.mark.slow
@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_the_first_lines_of_the_braid_hold_every_limit_and_the_tolerance(limits):
    """grbl's braid_cut2d at F7000 (test_no_give_ups.braid_program), its first 600 lines."""
    from tests.planning.lookahead.test_no_give_ups import BRAID
    lines = BRAID.read_text().splitlines()[:600]
    lines[0], lines[5] = "(T1M6)", "G1Z-1.000F7000"
    program = parse_gcode("\n".join(lines) + "\n", "braid_cut2d.nc")
    trajectory = plan_lookahead(program, limits)
    assert_blended_plan_holds(trajectory, program, limits)


def test_blends_next_to_a_line_that_could_not_be_joined_still_meet_their_pieces():
    """A polyline (found by test_no_give_ups' random programs) where a blend meeting another on
    a short line fails its check and the line is not joined: the blends next to it are rebuilt
    for the plain trims (they kept the joined ones: a 0.07 mm gap, 6.7 x the acceleration limit
    at any feed)."""
    steps = [(0.25, -2.593), (2.734, -1.368), (0.8, 0.510), (1.181, 0.01), (0.724, 2.282), (0.843, 0.01),
             (1.556, 2.253), (2.184, 0.0), (1.153, -2.276), (0.842, -1.234), (0.854, 2.991), (2.172, 0.0),
             (1.085, 0.7), (0.1, 0.0), (1.1, 0.005)]
    points, heading = [np.zeros(3)], 0.0
    for length, angle in steps:
        heading += 0.05846 * angle
        points.append(points[-1] + length * np.array([np.cos(heading), np.sin(heading), 0.0]))
    program = polyline(points, feed_mm_s=249.0)
    pieces = planned_pieces(program, NO_JERK)
    for a, b in zip(pieces[:-1], pieces[1:]):
        ends = a.curve.points(np.array([a.u_end]))[0], b.curve.points(np.array([b.u_start]))[0]
        assert np.linalg.norm(ends[0] - ends[1]) <= 1e-9
    assert max(g2_joins(pieces)) <= 1e-9
    trajectory = plan_lookahead(program, replace(NO_JERK, period_s=0.002))
    assert_blended_plan_holds(trajectory, program, replace(NO_JERK, period_s=0.002))


def test_the_plan_command_measures_a_blended_program_on_its_blends(tmp_path, capsys):
    """`nurbsmotion plan` (and the daemon's trace) measure set-points on the planned path: the
    measured chord error of a blended zigzag agrees with what the planner verified, not the
    hundreds of um a blend's rows give against the programmed corners."""
    import json

    from nurbsmotion.cli import main

    program = tmp_path / "zigzag.nc"
    program.write_text("G21 G90 G64 P0.01\nG01 X0 Y0 F6000\n" + "".join(
        f"G01 X{2 * (i + 1)} Y{(i % 2) * 0.5:.1f}\n" for i in range(40)))
    assert main(["plan", "--json", str(program)]) == 0
    report = json.loads(capsys.readouterr().out)
    measured, verified = report["measured"]["max_chord_error_mm"], report["notes"]["verified_max_chord_error_mm"]
    assert report["notes"]["verified_max_path_deviation_mm"] > 0  # the corners were blended
    assert measured <= verified * 1.05 + 1e-9


@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_sharp_corner_at_a_slow_feed_is_blended_and_passed_near_its_feed(limits):
    """90 deg at 1 mm/s: its blend within 0.01 mm passes at more than SHARP_PASS_SHARE of the
    feed (with J = 50000 at ~2 mm/s), so it is blended instead of stopped (a V-carve's corners)."""
    program = polyline(turn(90.0), feed_mm_s=1.0)
    blends = [p for p in planned_pieces(program, limits) if p.corners is not None]
    assert len(blends) == 1
    trajectory = plan_lookahead(program, limits)
    assert trajectory.notes["stops"] == 0
    assert not rests_at(trajectory, turn(90.0)[1])
    assert speed_near(trajectory, turn(90.0)[1]) >= blend.SHARP_PASS_SHARE * 1.0 * 0.99
    assert_blended_plan_holds(trajectory, program, limits)


def test_a_sharp_corner_is_a_stop_where_its_blend_would_crawl():
    """The same 90 deg corner at 100 mm/s: its blend passes at ~2 mm/s (J = 50000), a crawl
    that costs as much as the stop: it stays one."""
    program = polyline(turn(90.0), feed_mm_s=100.0)
    assert not any(p.corners is not None for p in planned_pieces(program, LIMITS))
    assert rests_at(plan_lookahead(program, LIMITS), turn(90.0)[1])


@pytest.mark.parametrize("feed_mm_s", [0.1, 1.0])
def test_a_near_reversal_stays_a_stop_at_any_feed(feed_mm_s):
    theta = blend.SHARP_LIMIT_DEG + 10.0
    program = polyline(turn(theta), feed_mm_s=feed_mm_s)
    assert not any(p.corners is not None for p in planned_pieces(program, NO_JERK))
    assert rests_at(plan_lookahead(program, NO_JERK), turn(theta)[1])


def steps_mm_s(trajectory) -> np.ndarray:
    """Speed (mm/s) of the step ending at each row (row 0: 0)."""
    step = np.linalg.norm(np.diff(trajectory.position_mm, axis=0), axis=1) / trajectory.period_s
    return np.concatenate([[0.0], step])


@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_leaving_a_slow_block_speeds_up_from_the_blends_middle(limits):
    """A plunge at 0.5 mm/s, then a cut at 2 mm/s round a 90 deg corner: the blend keeps the
    plunge's feed to its middle and takes the cut's from there (LinuxCNC's blend runs at the
    larger feed throughout), so the cut's feed is reached earlier than at the blend's end."""
    program = parse_gcode("G1 Z-5 F30\nG1 X20 F120\n", "plunge.nc")
    blend_piece = next(p for p in planned_pieces(program, limits) if p.corners is not None)
    assert (blend_piece.feed_mm_s, blend_piece.feed_out_mm_s) == (0.5, 2.0)
    trajectory = plan_lookahead(program, limits)
    speed = steps_mm_s(trajectory)
    middle, end = blend_piece.curve.points(np.array([0.5, 1.0]))[:, :3]
    to_middle = np.linalg.norm(trajectory.position_mm - middle, axis=1)
    first_half = np.arange(len(speed)) <= int(np.argmin(to_middle))
    assert speed[first_half].max() <= 0.5 * (1.0 + 1e-6)
    assert speed_near(trajectory, end) > 0.5 * 1.5
    assert speed.max() <= 2.0 * (1.0 + 1e-6)
    assert_blended_plan_holds(trajectory, program, limits)


def test_entering_a_slow_block_keeps_the_slower_feed_on_the_whole_blend():
    program = parse_gcode("G1 X20 F120\nG1 Z-5 F30\n", "retract.nc")
    blend_piece = next(p for p in planned_pieces(program, NO_JERK) if p.corners is not None)
    assert (blend_piece.feed_mm_s, blend_piece.feed_out_mm_s) == (0.5, None)


@pytest.mark.parametrize("feed_mm_s", [16.7, 100.0, 200.0])
def test_without_jerk_limit_a_sharp_corner_is_blended_where_that_beats_the_stop(feed_mm_s, monkeypatch):
    """90 deg, no jerk limit: the blend passes at ~8 mm/s, below SHARP_PASS_SHARE of the feed,
    but crossing it (blend.crossing_loss_s) costs less than stopping (F / A and the held cycle)
    from 16.7 mm/s to 200 mm/s (grbl's braid: its plunge-to-cut corners at 116.7 mm/s), so it is
    blended; the plan with the corner forced to a stop is slower. With J it stays a stop."""
    program = polyline(turn(90.0), feed_mm_s=feed_mm_s)
    assert any(p.corners is not None for p in planned_pieces(program, NO_JERK))
    assert not any(p.corners is not None for p in planned_pieces(program, LIMITS))
    blended = plan_lookahead(program, NO_JERK)
    assert not rests_at(blended, turn(90.0)[1])
    assert_blended_plan_holds(blended, program, NO_JERK)
    monkeypatch.setattr(blend, "worth_blending", lambda points, *args, **kwargs: np.zeros(len(points), dtype=bool))
    stopped = plan_lookahead(program, NO_JERK)
    assert rests_at(stopped, turn(90.0)[1])
    assert blended.duration_s < stopped.duration_s


@pytest.mark.parametrize("theta_deg", [60.0, 90.0, 140.0])
def test_the_crossing_loss_is_its_speed_profile_integrated_along_the_blend(theta_deg):
    """crossing_loss_s against the same model integrated on the blend's own NURBS curve, 4001
    points instead of 65: v = min(F, sqrt(A / kappa), sqrt(w^2 + 2 A |s - s_w|)), the time over
    the blend less its length at F, and the ramps at A from its ends to F."""
    from nurbsmotion.geometry import corner_blend as cb

    th = np.radians(theta_deg)
    first = cb.line_pieces(np.array([[-20.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 0.0]]))
    second = cb.line_pieces(np.array([[0.0, 0.0, 0.0]]), np.array([[20 * np.cos(th), 20 * np.sin(th), 0.0]]))
    points = cb.blend_points(first, second, cb.trim_distances(first, second, np.array([0.01])))
    curve = cb.bezier_curve(points[0])
    u = np.linspace(0.0, 1.0, 4001)
    s, kappa = np.asarray(curve.arc_length(u)), np.asarray(curve.curvature(u))
    feed, accel = 116.7, 2500.0
    cap = np.minimum(feed, np.sqrt(accel / np.maximum(kappa, 1e-300)))
    k = int(np.argmin(cap))
    v = np.minimum(cap, np.sqrt(cap[k] ** 2 + 2.0 * accel * np.abs(s - s[k])))
    expected = (np.sum(np.diff(s) * (2.0 / (v[1:] + v[:-1]) - 1.0 / feed))
                + ((feed - v[0]) ** 2 + (feed - v[-1]) ** 2) / (2.0 * accel * feed))
    assert blend.crossing_loss_s(points, np.array([feed]), accel)[0] == pytest.approx(expected, rel=2e-3)


@pytest.mark.parametrize(("first", "blended"), [("G0", True), ("G1 F12000", False)])
def test_without_jerk_limit_a_rapid_meeting_a_feed_move_stays_a_stop_at_any_feed(first, blended):
    """A 90 deg corner into a rapid, both at 200 mm/s, no jerk limit: after a rapid it is blended
    (crossing beats stopping), after a feed move of the rapid's speed it stays a stop, as in
    LinuxCNC (tp.c handleModeChange: no blend between rapid and feed motions)."""
    limits = replace(NO_JERK, rapid_feed_mm_s=200.0)
    program = parse_gcode(f"G21 {first} X20\nG0 X20 Y20\n", "mode.nc")
    assert any(p.corners is not None for p in planned_pieces(program, limits)) == blended
    trajectory = plan_lookahead(program, limits)
    assert rests_at(trajectory, (20.0, 0.0, 0.0)) != blended
    assert_blended_plan_holds(trajectory, program, limits)
