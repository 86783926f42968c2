"""service.verify.rest_waits: the drives applied the plan, each row once, in order; held
only before, after, and where the plan itself rests (a streamed job waiting at rest for its
next chunk, which a loaded host makes common: the demo called that 'a DIFFERENT sequence')."""

import numpy as np

from nurbsmotion.service.verify import rest_waits

# 1-axis plan: moves 0 -> 3, rests at 3 (two equal rows), moves on to 5
PLAN = np.array([[0], [1], [3], [3], [4], [5]])


def test_the_plan_held_before_and_after_has_no_waits():
    assert rest_waits(np.array([[0], [0], [1], [3], [3], [4], [5], [5]]), PLAN) == 0


def test_holding_where_the_plan_rests_counts_the_cycles_waited():
    assert rest_waits(np.array([[0], [1], [3], [3], [3], [3], [4], [5]]), PLAN) == 2


def test_holding_during_motion_is_not_the_plan():
    assert rest_waits(np.array([[0], [1], [1], [3], [3], [4], [5]]), PLAN) is None


def test_a_skipped_or_foreign_row_is_not_the_plan():
    assert rest_waits(np.array([[0], [3], [3], [4], [5]]), PLAN) is None
    assert rest_waits(np.array([[0], [1], [3], [3], [4], [4.5], [5]]), PLAN) is None
    assert rest_waits(np.array([[0], [1], [3]]), PLAN) is None  # ended early
