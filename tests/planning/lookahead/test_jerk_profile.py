"""The jerk filter's peak plateaus (jerk_profile.py) and the sparse-table minima they use,
against direct computations."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from nurbsmotion.planning.lookahead import jerk_profile as jp
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.planning.lookahead.speed_limits import range_min
from nurbsmotion.planning.measure import measure

from .conftest import WANG_LIMITS, assert_within_limits


def direct_width(s: np.ndarray, x: np.ndarray, peak: int, level: float) -> float:
    """Length of the stretch around ``peak`` where x >= level, walking out point by point."""
    j = peak
    while j > 0 and x[j - 1] >= level:
        j -= 1
    left = s[0] if j == 0 else s[j - 1] + (level - x[j - 1]) / (x[j] - x[j - 1]) * (s[j] - s[j - 1])
    k = peak
    while k < len(x) - 1 and x[k + 1] >= level:
        k += 1
    right = s[-1] if k == len(x) - 1 else s[k] + (x[k] - level) / (x[k] - x[k + 1]) * (s[k + 1] - s[k])
    return right - left


def direct_level(s: np.ndarray, x: np.ndarray, peak: int, tau_f: float, allowance_mm: float) -> float:
    """Highest level passing the plateau test, by 60 bisection steps on direct_width."""
    lo, hi = 0.0, float(x[peak])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if direct_width(s, x, peak, mid) >= jp.PLATEAU_MARGIN * np.sqrt(mid) * tau_f + allowance_mm:
            lo = mid
        else:
            hi = mid
    return lo


@pytest.mark.parametrize("seed", range(6))
def test_plateau_levels_in_closed_form_match_a_bisection_on_the_width(seed):
    """Random profiles (flat tops and repeated values included): every sharp peak's level is
    the one a fine bisection on the directly measured width finds."""
    rng = np.random.default_rng(seed)
    checked = 0
    for _ in range(40):
        n = int(rng.integers(5, 90))
        s = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 0.6, n - 1))])
        x = rng.uniform(0.0, 4e4, n)
        if rng.random() < 0.5:
            x = np.round(x, -3)  # repeated values and flat tops
        x[0], x[-1] = 0.0, float(rng.choice([0.0, 500.0]))
        peaks = np.flatnonzero((x[1:-1] >= x[:-2]) & (x[1:-1] > x[2:]) & (x[1:-1] > 0)) + 1
        if len(peaks) == 0:
            continue
        tau_f, allowance = float(rng.uniform(0.005, 0.1)), float(rng.choice([0.0, 0.8]))
        levels = jp.plateau_levels(s, x, peaks, tau_f, allowance)
        expected = np.array([direct_level(s, x, int(p), tau_f, allowance) for p in peaks])
        np.testing.assert_allclose(levels, expected, rtol=0, atol=1e-9 * float(x.max()))
        checked += len(peaks)
    assert checked > 100


def test_range_min_matches_direct_minima():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 17, 1000):
        values = rng.normal(size=n)
        lo = rng.integers(0, n, 300)
        hi = np.minimum(lo + rng.integers(0, n, 300), n - 1)
        expected = np.array([values[a:b + 1].min() for a, b in zip(lo, hi)])
        assert np.array_equal(range_min(values, lo, hi), expected)


def accelerate_then_brake(v_top: float, accel: float, flat_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(s, x = v^2) of accelerating at ``accel`` to v_top, holding it ``flat_s`` seconds and
    braking at ``accel``, on a 0.1 mm grid."""
    ramp = v_top**2 / (2.0 * accel)
    flat = v_top * flat_s
    s = np.arange(0.0, 2.0 * ramp + flat, 0.1)
    x = np.minimum(np.minimum(2.0 * accel * s, v_top**2), 2.0 * accel * (2.0 * ramp + flat - s))
    return s, np.maximum(x, 0.0)


def test_a_peak_is_sharp_when_the_paths_tangential_jerk_tips_it_over():
    """+-0.4 A around a short flat top: the filter's jerk across it is 0.8 J (not sharp on a
    line); on a curve with |c|^2 v^3 = 0.3 J the set-points' tangential jerk is 1.1 J: sharp."""
    jerk, tau_f, v_top = 50000.0, 0.05, 190.0
    s, x = accelerate_then_brake(v_top, 0.4 * jerk * tau_f, 0.01)
    assert jp.peak_plateau_caps(s, x, tau_f, jerk) is None
    curvature_sq = np.full(len(s), 0.3 * jerk / v_top**3)
    caps = jp.peak_plateau_caps(s, x, tau_f, jerk, curvature_sq)
    assert caps is not None and caps.min() < x.max()
    flat_top = s[caps <= caps.min() * (1 + 1e-12)]
    assert flat_top[-1] - flat_top[0] >= jp.PLATEAU_MARGIN * np.sqrt(caps.min()) * tau_f


def test_wangs_curve_at_1_ms_with_a_jerk_limit_needs_no_repair_round(wang_program):
    """The planner's first round holds every limit on Wang's curve at T = 1 ms (the throughput
    benchmark's case): no re-planning of the window, every cycle measured within the limits."""
    limits = replace(WANG_LIMITS, period_s=0.001, axis_max_velocity_mm_s=None, axis_max_accel_mm_s2=None)
    trajectory = plan_lookahead(wang_program, limits)
    assert trajectory.notes["repairs"] == 0
    assert_within_limits(measure(trajectory, wang_program), limits)


def test_widened_dips_spread_each_limit_over_its_bands_half_width():
    """widen_dips against the definition: every inner limit v_j spreads over
    +-DIP_HALF_TIME L_j tau, L_j the level of its band (the first level >= v_j), out to the
    grid points at or beyond those ends; points outside ``spreads`` (at their piece's feed:
    feed_plateaus' part) do not spread."""
    from nurbsmotion.planning.lookahead.speed_limits import DIP_HALF_TIME, dip_levels, widen_dips

    rng = np.random.default_rng(5)
    for _ in range(60):
        n = int(rng.integers(3, 200))
        s = np.concatenate([[0.0], np.cumsum(rng.uniform(0.0, 0.5, n - 1))])
        v = rng.uniform(1.0, 200.0, n)
        v[rng.random(n) < 0.2] = np.inf
        tau = float(rng.uniform(0.001, 0.1))
        spreads = rng.random(n) < 0.8
        inner = np.where(spreads, v, np.inf)
        inner[0] = inner[-1] = np.inf
        expected = v.copy()
        if np.isfinite(inner).any():
            levels = dip_levels(inner)
            for j in np.flatnonzero(np.isfinite(inner)):
                half = DIP_HALF_TIME * levels[min(np.searchsorted(levels, inner[j]), len(levels) - 1)] * tau
                before, after = s <= s[j] - half, s >= s[j] + half
                lo = np.flatnonzero(before)[-1] if before.any() else 0
                hi = np.flatnonzero(after)[0] if after.any() else n - 1
                near = (np.arange(n) >= lo) & (np.arange(n) <= hi)
                near[0] = near[-1] = False
                expected[near] = np.minimum(expected[near], inner[j])
        np.testing.assert_array_equal(widen_dips(s, v, tau, spreads), expected)


@pytest.mark.parametrize("jerk", [50000.0, None], ids=["jerk", "no-jerk"])
def test_a_short_slower_block_between_fast_ones_is_never_passed_above_its_feed(jerk):
    """With the jerk filter the set-points' speed is the raw speed averaged over tau: a dip of
    the feed widened too little (main had +-0.75 v tau inside the grid points; the V-carve
    passed 8 of its feed moves up to 14 % above their feed) lets the average exceed it. Also
    fails with feed plateaus of F tau / 2 only (speed_limits.feed_plateaus: the step that ends
    on the block starts up to F T before it). Without a jerk limit that step alone passed it
    above its feed (the raw v^2 rises linearly to the rapid's previous grid point; the V-carve
    up to 1.44x, the butterfly 1.36x)."""
    from nurbsmotion.planning import PlanLimits
    from nurbsmotion.program import parse_gcode

    program = parse_gcode("G21 G90 G64 P0.01\nG1 X30 F6000\nG1 X30.4 F150\nG1 X60 F6000\n", "slow.nc")
    limits = PlanLimits(period_s=0.001, chord_error_mm=0.01, max_accel_mm_s2=2500.0, max_jerk_mm_s3=jerk,
                        default_feed_mm_s=100.0, rapid_feed_mm_s=200.0, path_tolerance_mm=0.01)
    trajectory = plan_lookahead(program, limits)
    speed = np.linalg.norm(np.diff(trajectory.position_mm, axis=0), axis=1) / trajectory.period_s
    slow = trajectory.block[1:] == 1
    assert slow.any()
    assert speed[slow].max() <= 2.5 * (1.0 + 1e-6)


def test_feed_plateaus_hold_each_pieces_feed_out_to_the_grid_points_beyond_its_reach():
    """feed_plateaus against the definition: each piece's feed F over the piece and F x
    plateau_s beyond its first and last point, out to the grid points at or beyond those."""
    from nurbsmotion.planning.lookahead.speed_limits import feed_plateaus

    rng = np.random.default_rng(11)
    for _ in range(60):
        n = int(rng.integers(2, 120))
        s = np.concatenate([[0.0], np.cumsum(rng.uniform(0.0, 0.5, n - 1))])
        piece = np.sort(rng.integers(0, 6, n)).astype(np.int32)
        feeds = rng.uniform(1.0, 200.0, 6)
        plateau_s = float(rng.uniform(0.001, 0.06))
        expected = np.full(n, np.inf)
        for k in np.unique(piece):
            mine = np.flatnonzero(piece == k)
            reach = feeds[k] * plateau_s
            before, after = s <= s[mine[0]] - reach, s >= s[mine[-1]] + reach
            lo = np.flatnonzero(before)[-1] if before.any() else 0
            hi = np.flatnonzero(after)[0] if after.any() else n - 1
            expected[lo:hi + 1] = np.minimum(expected[lo:hi + 1], feeds[k])
        np.testing.assert_array_equal(feed_plateaus(s, piece, feeds[piece], plateau_s), expected)


def test_last_below_and_flat_top_starts_match_a_walk():
    from nurbsmotion.planning.lookahead.speed_limits import last_below

    rng = np.random.default_rng(7)
    for _ in range(100):
        n = int(rng.integers(1, 120))
        values = np.round(rng.uniform(0.0, 10.0, n))
        ends = rng.integers(0, n + 1, 20)
        levels = rng.uniform(0.0, 11.0, 20)
        expected = [max([j for j in range(e) if values[j] < lv], default=-1) for e, lv in zip(ends, levels)]
        assert list(last_below(values, ends, levels)) == expected
        peaks = np.flatnonzero((values[1:-1] >= values[:-2]) & (values[1:-1] > values[2:])) + 1
        for peak, start in zip(peaks, jp.top_starts(values, peaks)):
            assert values[start:peak + 1].min() >= values[peak] * (1 - 1e-12)
            assert start == 0 or values[start - 1] < values[peak] * (1 - 1e-12)


def test_count_at_or_above_is_the_full_comparison():
    """The per-row bisection counts what comparing every level with every column counts,
    ties included (levels are often running-minimum values themselves)."""
    from nurbsmotion.planning.lookahead.jerk_profile import ROW_SEARCH_MIN_LEVELS, count_at_or_above

    rng = np.random.default_rng(3)
    for levels in (1, ROW_SEARCH_MIN_LEVELS - 1, ROW_SEARCH_MIN_LEVELS, 70):
        running_min = np.minimum.accumulate(np.round(rng.uniform(0.0, 50.0, (9, 40)), 0), axis=1)
        level = np.concatenate([running_min[:, rng.integers(0, 40, levels // 2)],
                                rng.uniform(-1.0, 51.0, (9, levels - levels // 2))], axis=1)
        expected = np.count_nonzero(running_min[:, None, :] >= level[:, :, None], axis=2)
        assert np.array_equal(count_at_or_above(running_min, level), expected)
