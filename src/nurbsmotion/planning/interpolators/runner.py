"""Cycle-by-cycle interpolation of a whole Program, as a controller runs it.

The program is cut into runs at sharp corners (pieces.py): where the tangent turns by more
than CORNER_ANGLE_DEG between blocks (or at a kink inside a block) the motion stops exactly
on the junction (the reverse table of the run ends there) and restarts from rest. Inside a run the motion is continuous:
a step that passes the end of a block carries its leftover into the next block.

Each cycle of a run:
1. the pre-interpolation linear acc/dec (Wang §III.A) raises the profile feed by a_l T up to
   the block's feed (a_l = V0 / t_l, V0 the run's highest feed, capped at a_max);
2. the slow-downs still to come cap it (slowdown.py), and the method's feed adaptation
   (wang/zhang: chord error and resultant acceleration at both ends of the step, then the
   resultant acceleration checked on the set-points themselves);
3. the reverse table gives V_achieve at the current remaining length; in the cycle where
   V_achieve <= V_next the step follows the table instead (reverse.py), which lands
   exactly on the stop;
4. the method's stepper turns the step length into the next parameter (Taylor, Zhang).

The last cycle of a run is closed by the table: its step is f L_1 <= a_l T² (f the phase
carried from the cycle the deceleration started) and ends exactly on the stop point, whose
set-point is the curve's end point itself; the feed reaches zero in that same cycle.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from nurbsmotion.errors import InputError
from nurbsmotion.planning.interpolators.feed import FeedLimits
from nurbsmotion.planning.interpolators.pieces import Piece, split_runs
from nurbsmotion.planning.interpolators.reverse import build_reverse_table
from nurbsmotion.planning.interpolators.slowdown import SlowdownProfile
from nurbsmotion.planning.interpolators.stepping import (
    CurvePath,
    PathPoint,
    Stepper,
    Vec,
    distance,
    radius_of_curvature,
)
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Program

MAX_CYCLES = 50_000_000
CHECK_ITERATIONS = 6  # re-steps of the set-point acceleration check
CHECK_TARGET = 0.99999  # aim this far inside a_max: lengthening a step also bends it more


@dataclass(frozen=True)
class Method:
    """One of the papers' algorithms: Taylor order, feed adaptation, Zhang's correction."""

    name: str
    taylor_order: int
    adaptive: bool
    correct: bool
    # Wang exactly as printed: limits at the current point only, eq. 27 with the previous
    # cycle's a_t, no planned slow-downs and no check on the set-points (for comparison)
    as_printed: bool = False


class RunPlanner:
    """Interpolates one run (from rest to rest) and appends its rows."""

    def __init__(self, pieces: list[Piece], method: Method, limits: PlanLimits):
        self.indices = [piece.block for piece in pieces]
        curves = [piece.curve for piece in pieces]
        self.period = limits.period_s
        self.feeds = [piece.feed_mm_s for piece in pieces]
        self.accel = min(max(self.feeds) / limits.acc_time_s, limits.max_accel_mm_s2)  # a_l = V0 / t_l
        self.path = CurvePath(curves)
        last = len(curves) - 1
        self.reversed_path = CurvePath(lambda j: curves[last - j].reversed(),
                                       [(c.u_min, c.u_max) for c in reversed(curves)])
        self.limits = FeedLimits(self.period, limits.chord_error_mm, limits.max_accel_mm_s2, method.adaptive)
        # wang: the Taylor predictor's relative step error, measured on the last step, scales
        # the next step, so the limits hold for the feed the set-points really show
        self.compensate = method.adaptive and not method.correct and not method.as_printed
        self.stepper = Stepper(method.taylor_order, method.correct, limits.chord_error_mm)
        # the reverse interpolation uses Wang's eq. 19 (second-order Taylor) for every method:
        # its chords are measured, so the predictor's error does not enter V_achieve
        self.table = build_reverse_table(self.reversed_path, self.feeds[::-1], self.accel, self.limits,
                                         Stepper(2, False, limits.chord_error_mm), self.period)
        ahead_limits = FeedLimits(self.period, limits.chord_error_mm, limits.max_accel_mm_s2,
                                  method.adaptive and not method.as_printed)
        self.slowdown = SlowdownProfile(curves, self.feeds, ahead_limits, self.accel)
        self.as_printed = method.as_printed
        self.end_x = tuple(float(v) for v in curves[-1].control_points[-1])  # the exact end point
        last = self.path.last
        self.table_j = [last - j for j in self.table.j]  # forward coordinates of the table points
        self.table_u = [self.path.u_min[last - j] + self.path.u_max[last - j] - u
                        for j, u in zip(self.table.j, self.table.u)]

    def forward_point(self, reverse_point: PathPoint) -> PathPoint:
        """A reverse-path point in forward coordinates: x' changes sign, x'' does not."""
        j = self.path.last - reverse_point.j
        u = self.path.u_min[j] + self.path.u_max[j] - reverse_point.u
        d1 = reverse_point.d1
        return PathPoint(j, u, reverse_point.x, (-d1[0], -d1[1], -d1[2]), reverse_point.d2)

    def keep_resultant_accel(self, here: PathPoint, before_x: Vec, point: PathPoint, step: float,
                             previous_step: float) -> tuple[PathPoint, float, bool]:
        """Wang eq. 24 checked on the set-points themselves: |p_{i+1} - 2 p_i + p_{i-1}| / T² <= a_max.

        The feed rules above are estimates (curvature at one point, the predictor's step
        error); when the step they chose still breaks the limit, shorten it along the tangent
        t: |D + (ℓ' - ℓ) t| = a_max T², D the second difference of the chosen step.
        """
        limit = self.limits.max_accel * self.period * self.period
        done = False
        for _ in range(CHECK_ITERATIONS):
            x, h = point.x, here.x
            d = (x[0] - 2.0 * h[0] + before_x[0], x[1] - 2.0 * h[1] + before_x[1], x[2] - 2.0 * h[2] + before_x[2])
            d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            if d2 <= limit * limit * (1.0 + 1e-9):
                break
            chord = distance(x, h)
            if chord <= 0.0:
                break
            t = ((x[0] - h[0]) / chord, (x[1] - h[1]) / chord, (x[2] - h[2]) / chord)
            along = d[0] * t[0] + d[1] * t[1] + d[2] * t[2]
            across2 = max(d2 - along * along, 0.0)
            if across2 >= limit * limit:  # the bend alone is too much: take the smallest resultant
                change = -along
            else:
                change = -along + math.copysign(math.sqrt(limit * limit - across2), along) * CHECK_TARGET
                if abs(change) > abs(along):
                    change = -along
            new_step = max(chord + change, 0.0) * step / chord
            if new_step <= 0.0 or abs(new_step - step) <= 1e-15:
                break
            point, step, done = self.stepper.step(self.path, here, new_step, previous_step)
        return point, step, done

    def remaining_at(self, here: PathPoint, k_ahead: int) -> tuple[float, int]:
        """Remaining table length S at ``here`` and the index of the first table point ahead."""
        table = self.table
        while k_ahead >= 0 and (self.table_j[k_ahead] < here.j or (
                self.table_j[k_ahead] == here.j and self.table_u[k_ahead] <= here.u)):
            k_ahead -= 1
        if k_ahead < 0:
            return 0.0, k_ahead
        return table.remaining_mm[k_ahead] + distance(table.x[k_ahead], here.x), k_ahead

    def run(self, rows: tuple[list, list, list, list], include_start: bool) -> None:
        block_rows, u_rows, x_rows, feed_rows = rows
        path, table, period = self.path, self.table, self.period
        here = path.start()
        if include_start:
            block_rows.append(self.indices[here.j])
            u_rows.append(here.u)
            x_rows.append(here.x)
            feed_rows.append(0.0)
        v_in = 0.0  # measured feed of the step that arrived here
        previous_step = 0.0
        profile = 0.0  # Wang's pre-interpolation linear acc/dec feed
        ramp = self.accel * period
        k_ahead = len(table) - 1  # index of the first table point not yet passed
        tracked = None  # remaining length while the table places the points
        radius_before = math.inf  # radius of curvature at the previous set-point
        before_x = here.x  # the previous set-point (at rest before the start)
        ratio = 1.0  # wang: measured chord / predicted step length of the last step
        a_t_before = 0.0  # tangential acceleration of the last cycle (Wang eq. 27 as printed)
        end_x = self.end_x
        for _ in range(MAX_CYCLES):
            if tracked is None:
                s_now, k_ahead = self.remaining_at(here, k_ahead)
            else:
                s_now = tracked
            v_achieve = table.v_achieve(s_now)
            profile = min(profile + ramp, self.feeds[here.j])
            radius_here = radius_of_curvature(here.d1, here.d2)
            radius = min(radius_here, radius_before)  # the set-point's acceleration spans both steps
            # slow-downs still to come, read where this step will end (first-order estimate)
            d1 = here.d1
            u_end = here.u + (v_in + ramp) * period / math.sqrt(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2])
            ahead = self.slowdown.feed(here.j, u_end)
            if v_achieve != math.inf and v_achieve > ahead:
                ahead = v_achieve  # near the stop the table decides (it lands exactly)
            if self.as_printed:
                v_next = self.limits.feed_as_printed(min(profile, ahead), radius_here, a_t_before)
            else:
                v_next = self.limits.feed(min(profile, ahead), v_in, radius)
            done = False
            if v_achieve <= v_next:  # Wang: decelerate into the stop
                step = v_achieve * period
                tracked = s_now - step
                if tracked <= 1e-12 * (1.0 + s_now) or step <= 0.0:
                    point, done = path.end(), True
                    step = distance(end_x, here.x)
                else:
                    point = self.forward_point(table.point_at(tracked))
            else:  # the method's own step, at most V_achieve (slow-downs ahead)
                v_step = v_next
                point, step, done = self.stepper.step(path, here, v_step * period / ratio, previous_step)
                if not done and not self.as_printed:  # the step must also respect the limits where it ends
                    radius_after = radius_of_curvature(point.d1, point.d2)
                    v_after = self.slowdown.feed(point.j, point.u)
                    if radius_after < radius:
                        v_after = min(v_after, self.limits.feed(profile, v_in, radius_after))
                    if v_after < v_step * (1.0 - 1e-12):
                        v_step = v_after
                        point, step, done = self.stepper.step(path, here, v_step * period / ratio, previous_step)
                v_step = min(v_step, step * ratio / period)  # Zhang's midpoint rule may shorten it
                if self.limits.adaptive and not done and not self.as_printed:
                    checked, step, done = self.keep_resultant_accel(here, before_x, point, step, previous_step)
                    if checked is not point:
                        point, v_step = checked, step * ratio / period
                if self.compensate and step > 0.0 and not done:
                    ratio = distance(point.x, here.x) / step
                step = v_step * period  # the commanded feed of this step, times T
                tracked = None
            block_rows.append(self.indices[point.j])
            u_rows.append(point.u)
            x_rows.append(point.x)
            feed_rows.append(step / period)
            if done:
                x_rows[-1] = end_x
                return
            v_out = distance(point.x, here.x) / period
            a_t_before, v_in = (v_out - v_in) / period, v_out
            previous_step = step
            before_x = here.x
            here = point
            radius_before = radius_here
        raise RuntimeError("interpolation did not reach the end of the run")


def interpolate(program: Program, limits: PlanLimits, method: Method) -> Trajectory:
    """Plan ``program`` cycle by cycle with ``method``; one set-point per period."""
    started = time.perf_counter()
    rows: tuple[list, list, list, list] = ([], [], [], [])
    runs = split_runs(program, limits)
    for r, pieces in enumerate(runs):
        RunPlanner(pieces, method, limits).run(rows, include_start=(r == 0))
    block_rows, u_rows, x_rows, feed_rows = rows
    if not block_rows:
        if not program.blocks:
            raise InputError(program.name, "program has no motion blocks")
        start = program.blocks[0]
        block_rows, u_rows, x_rows, feed_rows = [0], [start.curve.u_min], [tuple(start.start)], [0.0]
    trajectory = Trajectory(
        algorithm=method.name,
        period_s=limits.period_s,
        block=np.asarray(block_rows, dtype=np.int32),
        u=np.asarray(u_rows, dtype=np.float64),
        position_mm=np.asarray(x_rows, dtype=np.float64),
        feed_mm_s=np.asarray(feed_rows, dtype=np.float64),
        notes={"runs": len(runs), "stops": max(len(runs) - 1, 0)},
    )
    trajectory.planning_time_s = time.perf_counter() - started
    return trajectory
