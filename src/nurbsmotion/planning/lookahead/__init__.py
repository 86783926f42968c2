"""``lookahead``: our planner. Look-ahead over the whole program, jerk-limited, near
time-optimal, and verified on every cycle the drives see.

Public API:
- ``plan_lookahead(program, limits) -> Trajectory`` (the registered algorithm);
- ``plan_lookahead_chunks(program, limits, chunk_cycles=2000, state=None) -> Iterator[Trajectory]``:
  the same set-points in consecutive chunks, planned with a bounded look-ahead window
  (bounded memory for programs of any length); ``Trajectory.concatenate`` joins them;
- ``plan_from_state(program, limits, state, chunk_cycles=2000) -> Iterator[Trajectory]``:
  re-plan from a moving state ``PlanState(s_mm, v_mm_s, a_mm_s2)`` (s along the planned
  path from its start), e.g. after a feed override: the first chunk starts with the
  set-point one cycle after the state;
- ``plan_lookahead_resumable(program, limits, chunk_cycles=2000, resume=None)
  -> Iterator[(Trajectory, Resume)]``: chunks with the exact state after each; continue from a
  ``Resume`` with new feed/chord/axis limits (a feed override at a chunk boundary), the join
  verified against the real last set-points and filter memory;
- ``planned_pieces(program, limits)``: the path planned along (short-segment runs smoothed,
  smoothing.py; corners blended within the path tolerance, blend.py): what a set-point's
  (block, u) refers to.
See docs/lookahead.md for the method and the guarantees.
"""

from __future__ import annotations

from nurbsmotion.planning.lookahead.api import (DEFAULT_CHUNK_CYCLES, GUARANTEES, PlanState, PlanStream, Resume,
                                                plan_from_state, plan_lookahead, plan_lookahead_chunks,
                                                plan_lookahead_resumable, planned_pieces)
from nurbsmotion.planning.lookahead.planner import PlanningError

ALGORITHMS = {"lookahead": plan_lookahead}

__all__ = ["ALGORITHMS", "DEFAULT_CHUNK_CYCLES", "GUARANTEES", "PlanState", "PlanStream", "PlanningError", "Resume",
           "plan_from_state", "plan_lookahead", "plan_lookahead_chunks", "plan_lookahead_resumable", "planned_pieces"]
