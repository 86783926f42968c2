"""benchmarks/bench_web.py's A/B verdict: the median of the rounds' paired differences and
its distribution-free interval (sign test), so one noisy round moves it by a rank; and where
the slack steps that overran a wake-up ended, job by job."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("aiohttp")
from benchmarks.bench_web import paired_median  # noqa: E402


def test_the_interval_is_the_widest_holding_ninety_percent_by_the_sign_test():
    # n = 8: P(B(8, 1/2) < 2) = 9/256, so [d_2, d_7] holds the median with 1 - 18/256 = 93 %
    median, low, high, confidence = paired_median([5.0, -3.0, 1.0, 40.0, -1.0, 2.0, 0.0, 300.0])
    assert (median, low, high) == (1.5, -1.0, 40.0)
    assert confidence == pytest.approx(1 - 18 / 256)
    # n = 10: [d_2, d_9], 1 - 2 * 11/1024; [d_3, d_8] would hold only 89 %
    median, low, high, confidence = paired_median([float(i) for i in range(10)])
    assert (median, low, high) == (4.5, 1.0, 8.0)
    assert confidence == pytest.approx(1 - 22 / 1024)


def test_one_outlier_moves_the_interval_by_a_rank_not_by_its_size():
    calm = [-2.0, -1.0, 0.0, 1.0, 2.0, 3.0, -3.0, 0.5]
    assert paired_median(calm)[:3] == (0.25, -2.0, 2.0)
    assert paired_median([*calm[:-1], 1e6])[:3] == (0.5, -2.0, 3.0)  # the outlier is d_8, outside [d_2, d_7]


def test_few_rounds_give_the_whole_range_with_the_confidence_it_has():
    assert paired_median([1.0, 3.0, 2.0]) == (2.0, 1.0, 3.0, 0.75)
    median, low, high, confidence = paired_median([])
    assert math.isnan(median) and confidence == 0.0


def test_the_overrun_places_of_a_job_are_the_counters_growth_summed_by_kind():
    from benchmarks.bench_web import overrun_places_summary, places_between

    assert places_between({"a:1": 2}, {"a:1": 3, "b:end": 1}) == {"a:1": 1, "b:end": 1}
    assert places_between({"a:1": 2}, {"a:1": 2}) == {}
    rows = [{"clients": "0", "overrun_places": {}},
            {"clients": "10 WebSocket", "overrun_places": {"a:1": 1, "b:end": 2}},
            {"clients": "10 WebSocket", "overrun_places": {"a:1": 2}}]
    assert overrun_places_summary(rows).splitlines()[2:] == ["- 0: none", "- 10 WebSocket: a:1 x3, b:end x2"]
