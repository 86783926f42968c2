"""The path grid (planning/lookahead/path.py): each piece's grid spacing follows its own feed,
so a slow cut in a program with fast rapids is not planned on the rapids' coarse grid."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.planning.lookahead.path import BlockPiece, build_grid
from nurbsmotion.planning.lookahead.planner import REPAIR_REACH_CYCLES, repair_reach_mm, settings_for
from nurbsmotion.program import parse_gcode

LIMITS = PlanLimits(period_s=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0, default_feed_mm_s=200.0,
                    rapid_feed_mm_s=200.0, path_tolerance_mm=0.01)
NO_JERK = replace(LIMITS, max_jerk_mm_s3=None)


def piece(block: int, a, b, feed_mm_s: float) -> BlockPiece:
    curve = line_curve(a, b)
    return BlockPiece(block, curve, curve.u_min, curve.u_max, feed_mm_s)


def test_each_piece_is_gridded_at_its_own_feed():
    pieces = (piece(0, [0, 0, 0], [10, 0, 0], 200.0), piece(1, [10, 0, 0], [10, 1, 0], 2.5))
    grid = build_grid(pieces, 0.8, feed_step_s=0.004, min_spacing_mm=0.005)
    fast, slow = (np.diff(grid.s[grid.piece == k]) for k in (0, 1))
    assert fast.max() <= 0.8 + 1e-12 and fast.max() > 0.5
    assert slow.max() <= 0.01 + 1e-12  # 2.5 mm/s x 4 ms
    coarse = build_grid(pieces, 0.8)
    assert np.diff(coarse.s[coarse.piece == 1]).max() > 0.5  # without feed_step_s: one spacing for all


def test_a_piece_next_to_a_slower_one_has_a_grid_point_where_the_slower_feeds_plateau_ends():
    """build_grid(plateau_s): a point F x plateau_s from the junction with a slower piece (F its
    feed; exact on a line, up to PLATEAU_POINT_MARGIN beyond on a curve), on both sides of the
    slower piece and in neither slower piece itself; without plateau_s none."""
    from nurbsmotion.planning.lookahead.path import PLATEAU_POINT_MARGIN

    pieces = (piece(0, [0, 0, 0], [0, 0, 10], 200.0), piece(1, [0, 0, 10], [0, 0, 9], 2.5),
              piece(2, [0, 0, 9], [5, 0, 9], 200.0))
    plateau_s = 0.026
    grid = build_grid(pieces, 0.4, plateau_s=plateau_s)
    reach = 2.5 * plateau_s * (1.0 + PLATEAU_POINT_MARGIN)
    first, last = (grid.s[grid.piece == 1][k] for k in (0, -1))
    assert np.min(np.abs(grid.s - (first - reach))) < 1e-9
    assert np.min(np.abs(grid.s - (last + reach))) < 1e-9
    plain = build_grid(pieces, 0.4)
    assert len(grid) == len(plain) + 2
    assert np.array_equal(grid.s[grid.piece == 1], plain.s[plain.piece == 1])


# a rapid sets the program's highest feed (200 mm/s); the cut at 2.5 mm/s starts from rest
# (the plunge's corner) on a run with a blended 5.7 deg corner, so the general planner plans it
SLOW_CUT = "G21 G90 G64 P0.01\nG0 X5\nG1 Z-1 F150\nY1\nX5.1 Y2\n"


@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_slow_cut_after_rapids_reaches_its_feed_as_fast_as_the_limits_allow(limits):
    program = parse_gcode(SLOW_CUT, "slow_cut.nc")
    trajectory = plan_lookahead(program, limits)
    cut = np.flatnonzero(trajectory.block == 2)  # Y1: from rest at the plunge's end
    speed = trajectory.feed_mm_s[cut]
    moving = int(np.argmax(speed > 0))
    reached = int(np.argmax(speed >= 0.9 * 2.5))
    assert speed[reached] >= 0.9 * 2.5
    tau_cycles = 0 if limits.max_jerk_mm_s3 is None else limits.max_accel_mm_s2 / limits.max_jerk_mm_s3 / limits.period_s
    # at A = 2500 mm/s^2, 2.25 mm/s is one cycle away (the jerk filter adds its averaging time);
    # on the rapids' 0.4-0.8 mm grid the raw profile, linear in v^2, took 290-580 cycles
    assert reached - moving <= tau_cycles + 10


# camotics_vcarve.ngc lines 1726-1730 (as the race reads them): a plunge, two cuts at
# 2.54 mm/s, a rapid up; without J the cut's kink into the rapid is passed at ~2.7 mm/s and
# repaired (a 7 % acceleration excess there)
VCARVE_STROKE = """G21 G90 G64 P0.01
G0 X3.7086540 Y2.0564094 Z0
G1 Z-0.364617 F152.4
X3.5337242 Y1.3100304 Z-0.1022604
X3.44297 Y1.20777 Z0
G0 Z2.54
"""


def test_a_repair_at_a_slow_cut_reaches_only_as_far_as_the_cuts_own_grid(monkeypatch):
    """planner.repair lowers the speed caps within the filter's reach plus two grid intervals
    of the violating set-point: of the cut's own grid (planner.repair_reach_mm), not the
    rapids' 0.8 mm, which slowed the whole stroke to 0.9 of its feed. The stroke needs no
    repair since the pieces' feed plateaus (speed_limits.feed_plateaus) hold the cut's feed
    one step into its neighbours; without them it violates the acceleration limit once, as
    it did when the repair reach was fixed."""
    from nurbsmotion.planning.lookahead import planner

    program = parse_gcode(VCARVE_STROKE, "vcarve_stroke.nc")
    trajectory = plan_lookahead(program, NO_JERK)
    assert trajectory.notes["repairs"] == 0
    assert np.median(trajectory.feed_mm_s[trajectory.block == 2]) >= 0.99 * 2.54
    monkeypatch.setattr(planner, "feed_plateaus", lambda s, *_: np.full(len(s), np.inf))
    trajectory = plan_lookahead(program, NO_JERK)
    assert trajectory.notes["repairs"] >= 1
    cut = trajectory.feed_mm_s[trajectory.block == 2]
    assert np.median(cut) >= 0.99 * 2.54


def test_a_repairs_reach_is_the_grid_there_but_some_cycles_at_the_feed_at_least():
    """planner.repair_reach_mm: on a fast line two grid intervals (at most two of the widest
    spacing); where short fast lines meet (intervals of micrometres) REPAIR_REACH_CYCLES cycles
    at their feed; on a slow piece its own fine grid, not the rapids' spacing."""
    settings = settings_for(NO_JERK, 200.0, 1000)  # widest spacing 0.8 mm at T = 1 ms
    pieces = (piece(0, [0, 0, 0], [10, 0, 0], 200.0), piece(1, [10, 0, 0], [10.002, 0, 0], 100.0),
              piece(2, [10.002, 0, 0], [10.002, 0.002, 0], 100.0), piece(3, [10.002, 0.002, 0], [10.002, 1, 0], 2.5))
    grid = build_grid(pieces, settings.spacing_mm, settings.feed_step_s, 0.005)
    reach = repair_reach_mm(grid, np.array([5.0, 10.003, 10.5]), settings)
    assert 1.0 < reach[0] <= 2.0 * settings.spacing_mm  # two 0.8 mm intervals at most
    assert reach[1] == pytest.approx(REPAIR_REACH_CYCLES * 100.0 * NO_JERK.period_s)  # 1.6 mm, not 4 um
    assert reach[2] == pytest.approx(REPAIR_REACH_CYCLES * 2.5 * NO_JERK.period_s)  # 0.04 mm, not 1.6
