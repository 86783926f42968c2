"""Deadline grid: lateness, missed cycles and the whole-period shift after a miss."""

import pytest

from nurbsmotion.fieldbus.cycle import DeadlineGrid, LatenessStats


def test_on_time_cycles_follow_the_absolute_grid():
    grid = DeadlineGrid(0.001, 10.0)
    lateness, missed = grid.advance(10.00002)
    assert lateness == pytest.approx(2e-5) and not missed
    assert grid.next_s == pytest.approx(10.001)  # not 'woke + T'


def test_a_missed_cycle_moves_the_grid_by_whole_periods():
    grid = DeadlineGrid(0.001, 10.0)
    lateness, missed = grid.advance(10.0035)
    assert missed and lateness == pytest.approx(0.0035)
    assert grid.next_s == pytest.approx(10.004)


def test_percentiles_and_counts():
    stats = LatenessStats(late_threshold_s=50e-6)
    for i in range(100):
        stats.add(i * 1e-6, missed=False)
    stats.add(5e-3, missed=True)
    assert stats.count == 101 and stats.missed == 1
    assert stats.late == 50  # 51..99 µs and the 5 ms one
    assert stats.percentile_s(0.5) == pytest.approx(51e-6)
    assert stats.max_s == pytest.approx(5e-3)
    assert 5.0e-3 <= stats.percentile_s(1.0) <= 5.1e-3 + 1e-9  # coarse 100 µs bins above 1 ms


def test_lateness_beyond_the_histogram_is_counted_in_the_last_bin():
    stats = LatenessStats(late_threshold_s=1e-4)
    stats.add(1.5, missed=True)
    assert stats.percentile_s(0.5) <= 0.1 and stats.max_s == 1.5 and stats.missed == 1


def test_kernel_sync_grid_counts_half_a_period_late_as_missed():
    grid = DeadlineGrid(0.004, 10.0, missed_after_s=0.002)
    lateness, missed = grid.advance(10.0025)
    assert missed
    assert grid.next_s == pytest.approx(10.004)  # still the same grid: less than a period late


@pytest.mark.parametrize("seed", range(5))
def test_a_percentile_is_the_upper_edge_of_the_bin_holding_that_sample(seed):
    """Oracle: the sorted samples' ceil(q n)-th sample, rounded up to its bin's upper edge."""
    import math
    import random

    rng = random.Random(seed)
    samples = [rng.choice([abs(rng.gauss(4e-4, 3e-4)), rng.uniform(1e-3, 0.08), 0.0]) for _ in range(rng.randint(1, 4000))]
    stats = LatenessStats(late_threshold_s=5e-4)
    for s in samples:
        stats.add(s, missed=False)
    ordered = sorted(samples)
    for q in (0.01, 0.5, 0.9, 0.99, 1.0):
        sample = ordered[max(0, math.ceil(q * len(ordered)) - 1)]
        edge = (int(sample / 1e-6) + 1) * 1e-6 if sample < 1e-3 else 1e-3 + (int((sample - 1e-3) / 1e-4) + 1) * 1e-4
        assert stats.percentile_s(q) == pytest.approx(edge, abs=1e-12), q
