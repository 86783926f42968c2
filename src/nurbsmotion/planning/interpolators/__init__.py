"""The papers' interpolators, cycle by cycle: taylor1, taylor2, wang, zhang.

- ``taylor1``: first-order Taylor u_{i+1} = u_i + V T / |x'| at constant feed (baseline);
- ``taylor2``: second-order Taylor with the dV/dt term (reference §1, corrected);
- ``wang``: taylor2 + chord-error and resultant-acceleration feed adaptation (Wang eq. 21-28)
  + linear acc/dec with reverse interpolation for the deceleration point (Wang eq. 18-20);
- ``zhang``: wang + Zhang's correction of u every cycle (chord = step, safeguarded Newton)
  and the midpoint chord-error estimate (Zhang eq. 12, 15).

All four share the start/stop handling (linear acc/dec a_l = V0 / t_l, reverse table), so
the baselines differ from the papers' methods only in what the papers changed; see
runner.py for the cycle and reverse.py for how the last cycle lands on the end point.
Jerk and per-axis limits are not used by these methods (the ``lookahead`` planner does).
"""

from __future__ import annotations

from nurbsmotion.planning.interpolators.pieces import CORNER_ANGLE_DEG, split_runs
from nurbsmotion.planning.interpolators.runner import Method, interpolate
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Program

METHODS = {
    "taylor1": Method("taylor1", taylor_order=1, adaptive=False, correct=False),
    "taylor2": Method("taylor2", taylor_order=2, adaptive=False, correct=False),
    "wang": Method("wang", taylor_order=2, adaptive=True, correct=False),
    "zhang": Method("zhang", taylor_order=2, adaptive=True, correct=True),
    # not registered as an algorithm: Wang's feed adaptation exactly as printed, for comparison
    "wang-as-printed": Method("wang-as-printed", taylor_order=2, adaptive=True, correct=False, as_printed=True),
}


def plan_taylor1(program: Program, limits: PlanLimits) -> Trajectory:
    return interpolate(program, limits, METHODS["taylor1"])


def plan_taylor2(program: Program, limits: PlanLimits) -> Trajectory:
    return interpolate(program, limits, METHODS["taylor2"])


def plan_wang(program: Program, limits: PlanLimits) -> Trajectory:
    return interpolate(program, limits, METHODS["wang"])


def plan_zhang(program: Program, limits: PlanLimits) -> Trajectory:
    return interpolate(program, limits, METHODS["zhang"])


ALGORITHMS = {"taylor1": plan_taylor1, "taylor2": plan_taylor2, "wang": plan_wang, "zhang": plan_zhang}

__all__ = ["ALGORITHMS", "CORNER_ANGLE_DEG", "METHODS", "Method", "interpolate", "split_runs"]
