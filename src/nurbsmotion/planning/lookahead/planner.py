"""The look-ahead planner: windows of path, verify-and-repair, set-points in chunks.

A run (runs.py: blocks between exact stops) is planned window by window. A window starts
at the last committed set-point (its raw-profile state carried along) and reaches far
enough ahead that the profile of its first part no longer depends on where it ends: the
window is scanned twice, once ending at rest and once ending free, and only the set-points
planned before the two scans part are committed. The last window of a run ends at rest on a
cycle boundary (jerk_profile.cycle_times / warped_cycle_times).

Every window is verified on its set-points (verify.py); where a cycle violates a limit, the
speed cap is lowered around it by the violation ratio (REPAIR_MARGIN, exponent of the
figure's speed dependence) and the window re-planned, at most MAX_REPAIR_ROUNDS times; a
window that stays in violation raises PlanningError naming the block.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead import jerk_profile as jp
from nurbsmotion.planning.lookahead import straight
from nurbsmotion.planning.lookahead.path import BlockPiece, PathGrid, build_grid, coarse_lengths, set_point_blocks
from nurbsmotion.planning.lookahead.runs import Run, planned_jerk_mm_s3
from nurbsmotion.planning.lookahead.sampling import Samples, sample_path
from nurbsmotion.planning.lookahead.scan import interval_bounds, speed_profile
from nurbsmotion.planning.lookahead.speed_limits import (DIP_HALF_TIME, DIP_WIDTH_FACTOR, MARGIN, AccelBounds, Caps,
                                                         feed_plateaus, static_speed_limit, tangential_jerk_share,
                                                         widen_dips)
from nurbsmotion.planning.lookahead.verify import Check, MachineLimits, check

MAX_REPAIR_ROUNDS = 16
MAX_STALLED_REPAIRS = 4  # repair rounds in a row that do not lower the worst violation: the repair diverges
SHARE_ROUNDS = 2  # re-evaluations of the tangential jerk share at the planned speeds (first round)
REPAIR_MARGIN = 0.97
REPAIR_REACH_CYCLES = 16.0  # a repair reaches at least this many cycles at the feed beyond the filter (repair_reach_mm)
ACCEL_REPAIR_FACTOR = 0.8  # tangential acceleration scale after an acceleration/jerk violation
EXPONENTS = {"chord": 2.0, "accel": 2.0, "jerk": 3.0, "axis_velocity": 1.0, "axis_accel": 2.0}
GRID_STEPS = 2.0  # path grid spacing in feed steps (F T), with the jerk filter ...
MAX_SPACING_MM = 0.5
GRID_STEPS_FREE = 4.0  # ... and without it: the grid only samples the speed limits, the
MAX_SPACING_FREE_MM = 1.0  # profile between its points is exact (no plateaus on grid points)
MIN_SPACING_MM = 0.005
WINDOW_CUT_FACTOR = 1.5  # a block reaching past this x the window length is cut inside
PART_TOLERANCE = 1e-9
START_BRAKE_SHARE = 1.0  # share of A (already x MARGIN) used to brake from a running start above the new caps
BRAKE_ROUNDS = 3
START_BRAKE_SHARE_FILTERED = 0.7  # with the jerk filter: the step into braking is a jerk of share x J
MAX_BACKTRACKS = 4  # re-plans of a held-back window for the sake of the next one
MAX_WINDOW_CYCLES = 10_000_000  # a window planned slower than this cannot move: an error, not a crawl
NO_CAP = 1e30  # mm/s: a speed cap that never binds (finite, so caps can be interpolated)  # relative difference at which the stop and free scans are said to part


class PlanningError(InputError):
    """The limits cannot be held on every cycle at some place of the program.

    ``block`` is the program block's index (0-based) where known: the API replaces the
    ``where`` with that block's source line (api.at_program_line)."""

    def __init__(self, where: str, message: str, block: int | None = None) -> None:
        super().__init__(where, message)
        self.block = block



def axis_limit_array(values: tuple[float | None, ...] | None, scale: float = 1.0) -> NDArray[np.float64] | None:
    """Per-axis X, Y, Z limits times ``scale``; an axis without a limit (None, or not given)
    is unlimited (inf). A None must not become NaN: NaN would drop every axis's cap (min and
    comparisons with NaN), so the given limits would not hold either."""
    if values is None:
        return None
    given = [np.inf if v is None else v for v in values[:3]]
    out = np.full(3, np.inf)
    out[: len(given)] = np.asarray(given, dtype=np.float64) * scale
    return out


def caps_for(limits: PlanLimits) -> Caps:
    jerk = planned_jerk_mm_s3(limits)

    def axis(values: tuple[float | None, ...] | None) -> NDArray[np.float64] | None:
        return axis_limit_array(values, MARGIN)

    return Caps(period_s=limits.period_s, chord_error_mm=MARGIN * limits.chord_error_mm,
                accel_mm_s2=MARGIN * limits.max_accel_mm_s2,
                jerk_mm_s3=None if jerk is None else MARGIN * jerk,
                axis_velocity_mm_s=axis(limits.axis_max_velocity_mm_s), axis_accel_mm_s2=axis(limits.axis_max_accel_mm_s2))


def machine_for(limits: PlanLimits) -> MachineLimits:
    return MachineLimits(limits.period_s, limits.chord_error_mm, limits.max_accel_mm_s2, limits.max_jerk_mm_s3,
                         axis_limit_array(limits.axis_max_velocity_mm_s), axis_limit_array(limits.axis_max_accel_mm_s2))


def averaging_time_s(limits: PlanLimits) -> float:
    """tau_f = A / J of the jerk filter (0 without a jerk limit, or one the acceleration limit
    already implies: runs.planned_jerk_mm_s3)."""
    jerk = planned_jerk_mm_s3(limits)
    return 0.0 if jerk is None else limits.max_accel_mm_s2 / jerk


Carry = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]  # run s, speed caps, accel scales


@dataclass
class Cursor:
    """Where the next window of a run starts: the last committed set-point and the raw state."""

    piece_index: int  # into run.pieces
    u: float
    raw_offset_mm: float = 0.0  # raw position ahead of the set-point
    raw_speed_mm_s: float = 0.0
    history: jp.RawProfile | None = None  # raw pieces before t = 0 (window coordinates)
    before: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    previous: Samples | None = None
    at_rest: bool = True  # the run starts here: sample t = 0 too
    run_s_mm: float = 0.0  # arc length along the run at the cursor
    carry: Carry | None = None  # repairs so far


@dataclass(eq=False)
class WindowPlan:
    samples: Samples
    s: NDArray[np.float64]
    planned_ds: NDArray[np.float64]
    check: Check
    repairs: int
    final: bool
    cursor: Cursor | None
    blocks: NDArray[np.int32]
    stop: WindowPlan | None = None  # a non-final window's set-points all the way to its verified stop
    run: Run | None = None  # the run the plan belongs to, when plan_run had to split or slow its run
    start_piece: int = 0  # index into the run's pieces of the window's first piece
    early_stop: bool = False  # a stop before the run's end (the planner's fallback)
    fallback: str = ""  # set on the first plan of a run the fallback made: FALLBACK_STOP/_SPLIT/_SLOWER
    discarded: int = 0  # window plans thrown away before this one (failed, too short, or re-planned held-back)

    def next_cursor(self) -> Cursor:
        """Where the next window starts: every non-final window has one."""
        if self.cursor is None:
            raise ValueError("a final window has no next cursor")
        return self.cursor

    def verified_stop(self) -> WindowPlan:
        """The set-points to the window's verified stop: every non-final window has them."""
        if self.stop is None:
            raise ValueError("a final window has no separate stop")
        return self.stop


@dataclass
class PlanSettings:
    limits: PlanLimits
    caps: Caps
    machine: MachineLimits
    tau_f: float
    spacing_mm: float
    window_mm: float
    stop_mm: float  # distance to stop from the highest feed (with the jerk filter's delay)
    max_feed_mm_s: float = 0.0
    tangential_share: float = 1.0  # raw tangential acceleration A x share, filter time tau_f x share
    feed_step_s: float = 0.0  # a piece's grid spacing at most its feed x this (path.build_grid); 0: spacing_mm

    @property
    def feed_plateau_s(self) -> float:
        """A piece's feed F holds F x this beyond its ends (speed_limits.feed_plateaus): the
        filter's half window, and one cycle more for the step that ends on the piece from
        before it (also without a filter: the raw speed there rises linearly in v^2 to the
        previous grid point, a whole rapid interval away)."""
        return DIP_HALF_TIME * self.tau_f + self.limits.period_s

    @property
    def min_pass_mm_s(self) -> float:
        """Slowest junction speed passed moving: its widened plateau must span a grid interval."""
        return 0.0 if self.tau_f <= 0 else self.spacing_mm / (DIP_WIDTH_FACTOR * self.tau_f)


def settings_for(limits: PlanLimits, max_feed_mm_s: float, chunk_cycles: int) -> PlanSettings:
    tau_f = averaging_time_s(limits)
    steps, widest = (GRID_STEPS, MAX_SPACING_MM) if tau_f > 0 else (GRID_STEPS_FREE, MAX_SPACING_FREE_MM)
    spacing = float(np.clip(steps * max_feed_mm_s * limits.period_s, MIN_SPACING_MM, widest))
    stop = max_feed_mm_s**2 / limits.max_accel_mm_s2 + 2.0 * max_feed_mm_s * tau_f
    window = max(chunk_cycles * limits.period_s * max_feed_mm_s, 1.0) + 3.0 * stop
    return PlanSettings(limits, caps_for(limits), machine_for(limits), tau_f, spacing, window, stop, max_feed_mm_s,
                        feed_step_s=steps * limits.period_s)


def window_pieces(run: Run, cursor: Cursor, length_mm: float) -> tuple[tuple[BlockPiece, ...], tuple[float, ...], bool]:
    """Pieces from the cursor on, about ``length_mm`` long (or to the run's end); a long block
    is cut inside (at the approximate arc length that completes the window)."""
    pieces: list[BlockPiece] = []
    total = 0.0
    i = cursor.piece_index
    while True:
        piece = run.pieces[i]
        u_start = cursor.u if i == cursor.piece_index else piece.u_start
        u, along = coarse_lengths(piece.curve, u_start, piece.u_end)
        if total + along[-1] > WINDOW_CUT_FACTOR * length_mm:
            u_cut = float(np.interp(max(length_mm - total, MIN_SPACING_MM), along, u))
            pieces.append(replace(piece, u_start=u_start, u_end=u_cut))
            return tuple(pieces), run.junction_speed_mm_s[cursor.piece_index:i], False
        pieces.append(replace(piece, u_start=u_start))
        total += along[-1]
        if i + 1 == len(run.pieces):
            return tuple(pieces), run.junction_speed_mm_s[cursor.piece_index:i], True
        if total >= length_mm:
            return tuple(pieces), run.junction_speed_mm_s[cursor.piece_index:i], False
        i += 1


def speed_caps(grid: PathGrid, settings: PlanSettings, junction_speeds: tuple[float, ...],
               speed_cap: NDArray[np.float64], bounds: AccelBounds, static_mm_s: NDArray[np.float64]) -> NDArray[np.float64]:
    """x = v^2 cap of every grid point from all constraints (``static_mm_s``: the grid's
    static_speed_limit), dips widened for the jerk filter: those below the piece's feed in
    speed bands (widen_dips), the pieces' feeds exactly (feed_plateaus)."""
    v = np.minimum(static_mm_s, speed_cap)
    ends = np.flatnonzero(grid.junction)
    for i, vj in zip(ends, junction_speeds):
        v[i] = min(v[i], vj)
        v[i + 1] = min(v[i + 1], vj)
    x = bounds.max_speed_squared(v**2)
    if settings.tau_f > 0:
        below_feed = x < grid.feed_mm_s**2
        x = widen_dips(grid.s, np.sqrt(x), settings.tau_f, below_feed) ** 2
    return np.minimum(x, feed_plateaus(grid.s, grid.piece, grid.feed_mm_s, settings.feed_plateau_s) ** 2)


def scan_grid(grid: PathGrid, start_mm: float) -> NDArray[np.intp]:
    """Grid indices the raw profile runs over: the first point at or after ``start_mm`` on."""
    return np.arange(int(np.searchsorted(grid.s, start_mm - 1e-12, side="left")), len(grid))


def braking_ramp(s: NDArray[np.float64], x0: float, bounds: AccelBounds, share: float) -> NDArray[np.float64]:
    """x = v^2 of braking from x0 at ``share`` of the deceleration every point allows at that
    speed (curvature and axis limits leave less than A): x_i = x0 - sum 2 d_k ds_k, with the
    bounds re-evaluated at the ramp's own speeds (they loosen as it slows)."""
    ds = np.diff(s)
    x = np.full(len(s), x0)
    for _ in range(BRAKE_ROUNDS):
        decel, _ = interval_bounds(bounds, np.maximum(x, 0.0))
        x = x0 - np.concatenate([[0.0], np.cumsum(2.0 * share * decel * ds)])
    return x


def raw_for(grid: PathGrid, idx: NDArray[np.intp], x_cap: NDArray[np.float64], bounds: AccelBounds,
            cursor: Cursor, end_free: bool, tau_f: float, plateaus: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(s, x) of the raw profile over grid points ``idx`` preceded by the raw start point;
    with the jerk filter (and ``plateaus``), sharp speed peaks are flattened (jp.peak_plateau_caps)."""
    points = slice(int(idx[0]), int(idx[-1]) + 1)  # scan_grid: consecutive points
    if grid.s[points.start] - cursor.raw_offset_mm <= 1e-12:  # start on a grid point
        s, cap = grid.s[points], x_cap[points].copy()
        cap[0] = cursor.raw_speed_mm_s**2
        sub = bounds.subset(points)
    else:
        s = np.concatenate([[cursor.raw_offset_mm], grid.s[points]])
        cap = np.concatenate([[cursor.raw_speed_mm_s**2], x_cap[points]])
        sub = bounds.subset(np.concatenate([idx[:1], idx]))
    ramp = None
    if cursor.raw_speed_mm_s > 0:
        # a running start above the caps (a lowered feed override): brake down to them
        share = START_BRAKE_SHARE if tau_f <= 0 else START_BRAKE_SHARE_FILTERED
        ramp = braking_ramp(s, cursor.raw_speed_mm_s**2, sub, share)
        cap = np.maximum(cap, ramp)
    if not end_free:
        cap[-1] = 0.0
    x = speed_profile(s, cap, sub)
    if plateaus and tau_f > 0 and bounds.caps.jerk_mm_s3 is not None:
        peak_caps = jp.history_peak_caps(s, x, tau_f, bounds.caps.jerk_mm_s3, sub.kappa**2, cursor.history)
        if peak_caps is not None:
            if ramp is not None:  # the start speed is committed: brake from it, never jump below it
                peak_caps = np.maximum(peak_caps, ramp)
            x = speed_profile(s, np.minimum(cap, peak_caps), sub)
    return s, x


def on_grid(grid: PathGrid, s_raw: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """x = v^2 of the raw profile (s_raw, x) at the grid points: x itself when the raw profile
    runs over the whole grid (a window starting at rest on its first point; at a junction's
    two points the scan's x is equal, ds = 0), else interpolated."""
    if len(s_raw) == len(grid) and np.array_equal(s_raw, grid.s):
        return x
    return np.interp(grid.s, s_raw, x)


def sample_times(raw: jp.RawProfile, cursor: Cursor, settings: PlanSettings, final: bool) -> NDArray[np.float64]:
    """Times of the set-points of this window (t = 0 is the cursor's set-point): to rest on a
    cycle boundary at the run's end; else every cycle until the window's stop."""
    period = settings.limits.period_s
    duration = raw.end_time_s + settings.tau_f
    if final:
        times = jp.cycle_times(duration, period) if cursor.at_rest else jp.warped_cycle_times(duration, period)
    else:
        times = np.arange(int(np.floor(duration / period)) + 1, dtype=np.float64) * period
    return times if cursor.at_rest else times[1:]


def carried_repairs(grid: PathGrid, cursor: Cursor) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Speed caps and acceleration scales the previous window's repairs set on this window's path."""
    speed_cap = np.full(len(grid), NO_CAP)
    accel_scale = np.ones(len(grid))
    if cursor.carry is not None:
        run_s, caps, scales = cursor.carry
        here = grid.s + cursor.run_s_mm
        speed_cap = np.interp(here, run_s, caps, left=NO_CAP, right=NO_CAP)
        accel_scale = np.interp(here, run_s, scales, left=1.0, right=1.0)
    return speed_cap, accel_scale


def plan_window(run: Run, cursor: Cursor, settings: PlanSettings, length_mm: float) -> WindowPlan:
    """Plan, sample, verify and repair one window of a run.

    A window that does not reach the run's end is sampled and verified up to its stop at the
    window's end, so the committed set-points always have a verified way to stop."""
    pieces, junction_speeds, reaches_end = window_pieces(run, cursor, length_mm)
    grid = build_grid(pieces, settings.spacing_mm, settings.feed_step_s, MIN_SPACING_MM, settings.feed_plateau_s)
    speed_cap, accel_scale = carried_repairs(grid, cursor)
    accel_scale *= settings.tangential_share
    static = static_speed_limit(grid, settings.caps)
    jerk_share = tangential_jerk_share(grid, settings.caps, settings.tau_f, 2.0 * settings.spacing_mm, None, static)
    idx = scan_grid(grid, cursor.raw_offset_mm)
    if len(idx) < 2:  # a running start whose filter memory already reaches past the run's end
        raise PlanningError(f"block {pieces[-1].block + 1}", "too close to the end of the motion to re-plan "
                            "from this state; keep the current plan", pieces[-1].block)
    period = settings.limits.period_s
    best_worst, stalled = np.inf, 0  # the smallest worst violation ratio so far, rounds since it fell
    for repairs in range(MAX_REPAIR_ROUNDS + 1):
        bounds = AccelBounds.for_grid(grid, settings.caps, accel_scale * jerk_share)
        x_cap = speed_caps(grid, settings, junction_speeds, speed_cap, bounds, static)
        speeds = None
        for _ in range(SHARE_ROUNDS if repairs == 0 and settings.tau_f > 0 else 0):
            # the share at the speeds a scan plans with it: a fixed point, from below and above
            # in turn (as in scan.speed_profile), damped by evaluating at the mean of the last
            # two scans' speeds; the peaks' plateaus only matter to the last scan
            s_raw, x = raw_for(grid, idx, x_cap, bounds, cursor, False, settings.tau_f, plateaus=False)
            planned = np.sqrt(np.maximum(on_grid(grid, s_raw, x), 0.0))
            speeds = planned if speeds is None else 0.5 * (speeds + planned)
            jerk_share = tangential_jerk_share(grid, settings.caps, settings.tau_f, 2.0 * settings.spacing_mm, speeds,
                                               static)
            bounds = AccelBounds.for_grid(grid, settings.caps, accel_scale * jerk_share)
            if bounds.speed_depends_on_scale:
                x_cap = speed_caps(grid, settings, junction_speeds, speed_cap, bounds, static)
        s_raw, x = raw_for(grid, idx, x_cap, bounds, cursor, False, settings.tau_f)
        commit_t = np.inf
        raw = jp.raw_profile(s_raw, x)
        if not reaches_end:
            _, x_free = raw_for(grid, idx, x_cap, bounds, cursor, True, settings.tau_f)
            parted = np.flatnonzero(x < x_free * (1 - PART_TOLERANCE) - 1e-12)
            part_s = s_raw[parted[0]] if len(parted) else s_raw[-1]
            # leave a stopping distance before the parting point, so a repair the next window
            # needs where this one did not look still has room to slow down
            k = int(np.searchsorted(raw.s, part_s - settings.stop_mm, side="left"))
            commit_t = float(raw.t[min(k, len(raw.t) - 1)]) - 2.0 * period
            if commit_t < 2.0 * period:
                raise _WindowTooShort()
        if raw.end_time_s > MAX_WINDOW_CYCLES * period:
            raise PlanningError(f"block {pieces[0].block + 1}", "lookahead finds no speed at which the limits "
                                f"hold here (the window would take {raw.end_time_s:.3g} s)", pieces[0].block)
        full_raw = jp.prepend_history(cursor.history, raw) if cursor.history is not None else raw
        times = sample_times(raw, cursor, settings, reaches_end)
        s = np.clip(jp.filtered_position(full_raw, times, settings.tau_f), 0.0, grid.length_mm)
        if reaches_end:
            s[-1] = grid.length_mm
        s = np.maximum.accumulate(s)
        samples = sample_path(grid, s)
        previous_s = np.concatenate([[0.0], s[:-1]]) if not cursor.at_rest else np.concatenate([[s[0]], s[:-1]])
        planned_ds = s - previous_s
        end = samples.position_mm[-1:]
        after = np.repeat(end, 3, axis=0)
        before = cursor.before if len(cursor.before) else np.repeat(samples.position_mm[:1], 3, axis=0)
        result = check(grid, samples, s, planned_ds, settings.machine, before, after, cursor.previous)
        bad = result.violations()
        if not bad:
            break
        worst = max(float(getattr(result, name).max()) for name in bad if name != "fluctuation") \
            if set(bad) != {"fluctuation"} else np.inf
        best_worst, stalled = (worst, 0) if worst < best_worst else (best_worst, stalled + 1)
        if repairs == MAX_REPAIR_ROUNDS or set(bad) == {"fluctuation"} or stalled >= MAX_STALLED_REPAIRS:
            raise _violation_error(pieces, samples, result, bad, repairs)
        repair(grid, s, idx, x, s_raw, bad, result, settings, speed_cap, accel_scale)
    blocks = set_point_blocks(pieces, samples.piece, samples.u)
    stop = None
    if not reaches_end:
        stop = WindowPlan(samples, s, planned_ds, result, repairs, True, None, blocks, start_piece=cursor.piece_index,
                          early_stop=True)
        keep = times <= commit_t
        residual = samples.arc_residual_mm
        samples = Samples(samples.piece[keep], samples.u[keep], samples.position_mm[keep],
                          None if residual is None else residual[keep])
        s, planned_ds, times, blocks = s[keep], planned_ds[keep], times[keep], blocks[keep]
    next_cursor = None
    if not reaches_end:
        next_cursor = next_window_cursor(run, cursor, pieces, samples, s, times, full_raw, settings)
        carry = merge_carry(cursor.carry, (grid.s + cursor.run_s_mm, speed_cap, accel_scale))
        ahead = carry[0] >= next_cursor.run_s_mm - settings.stop_mm  # bounded memory: forget what is passed
        next_cursor.carry = (carry[0][ahead], carry[1][ahead], carry[2][ahead])
    return WindowPlan(samples, s, planned_ds, result, repairs, reaches_end, next_cursor, blocks, stop,
                      start_piece=cursor.piece_index)


class _WindowTooShort(Exception):
    pass


def _violation_error(pieces: tuple[BlockPiece, ...], samples: Samples, result: Check, bad: dict,
                     repairs: int) -> PlanningError:
    name, rows = next(iter(bad.items()))
    row = int(rows[0])
    block = pieces[int(samples.piece[row])].block
    value = float(getattr(result, name if name != "fluctuation" else "arc_fluctuation")[row])
    return PlanningError(f"block {block + 1}", f"lookahead cannot hold the {name} limit here "
                         f"(figure {value:.6g} x the limit after {repairs} repairs)", block)


def repair(grid: PathGrid, s: NDArray[np.float64], idx: NDArray[np.intp], x: NDArray[np.float64],
           s_raw: NDArray[np.float64], bad: dict[str, NDArray[np.intp]], result: Check, settings: PlanSettings,
           speed_cap: NDArray[np.float64], accel_scale: NDArray[np.float64]) -> None:
    """Lower the speed cap around every violating set-point by its violation ratio."""
    v_grid = np.sqrt(np.maximum(np.interp(grid.s, s_raw, x), 0.0))
    v_rows = np.sqrt(np.maximum(np.interp(s, s_raw, x), 0.0))
    touched = np.zeros(len(grid), dtype=bool)
    for name, rows in bad.items():
        if name == "fluctuation":
            continue
        ratio = getattr(result, name)[rows]
        factor = (REPAIR_MARGIN / ratio) ** (1.0 / EXPONENTS[name])
        reach = settings.tau_f * v_rows[rows] + repair_reach_mm(grid, s[rows], settings)
        lo = s[np.maximum(rows - 3, 0)] - reach
        hi = s[np.minimum(rows + 2, len(s) - 1)] + reach
        k_lo = np.searchsorted(grid.s, lo, side="left")
        k_hi = np.searchsorted(grid.s, hi, side="right")
        for a, b, f, v_row in zip(k_lo, k_hi, factor, v_rows[rows]):
            # slower points nearby (a start from rest) are not pulled down below f x the row's speed
            speed_cap[a:b] = np.minimum(speed_cap[a:b], f * np.maximum(v_grid[a:b], v_row))
            if name in ("accel", "jerk", "axis_accel"):
                touched[a:b] = True
    accel_scale[touched] *= ACCEL_REPAIR_FACTOR  # once per round, however many rows overlap


def repair_reach_mm(grid: PathGrid, s_mm: NDArray[np.float64], settings: PlanSettings) -> NDArray[np.float64]:
    """A repair's reach beyond the filter's around each s: the two grid intervals there, at
    least REPAIR_REACH_CYCLES cycles at the piece's feed, at most two of the widest spacing.

    Two intervals of the widest spacing (the program's fastest feed's) spread a 7 % repair at
    a 2.5 mm/s junction over +-1.6 mm: the V-carve's cuts without J at 0.9 of their feed. The
    grid's own intervals alone are micrometres where short lines meet (every line end is a
    grid point): at such junctions the repairs of grbl's braid at T = 1 ms with path tolerance
    0 stalled at 1.00-1.10 x the accel limit in 12-30 windows, each of which (the whole
    program from rest) fell back to a stop one block further on: minutes of planning instead
    of seconds. Floors of 8 cycles (two intervals of a grid spaced by the piece's feed, without
    J) still left 12 fallback stops there, 16 none (2.8 s)."""
    k = np.searchsorted(grid.s, s_mm)
    last = len(grid.s) - 1
    local = grid.s[np.minimum(k + 1, last)] - grid.s[np.maximum(k - 1, 0)]
    floor = REPAIR_REACH_CYCLES * grid.feed_mm_s[np.minimum(k, last)] * settings.limits.period_s
    return np.minimum(np.maximum(local, floor), 2.0 * settings.spacing_mm)


def next_window_cursor(run: Run, cursor: Cursor, pieces: tuple[BlockPiece, ...], samples: Samples,
                       s: NDArray[np.float64], times: NDArray[np.float64], raw: jp.RawProfile,
                       settings: PlanSettings) -> Cursor:
    """The cursor at the window's last committed set-point (raw state and history moved along)."""
    t_cut, s_cut = float(times[-1]), float(s[-1])
    raw_s = float(raw.position(np.array([t_cut]))[0])
    k, tau = raw.locate(np.array([t_cut]))
    raw_v = float(raw.v[k[0]] + raw.a[k[0]] * tau[0])
    history = None
    if settings.tau_f > 0:
        history = jp.shifted(jp.history_before(raw, t_cut, settings.tau_f + settings.limits.period_s), -t_cut, -s_cut)
    piece = pieces[int(samples.piece[-1])]
    piece_index = cursor.piece_index + int(samples.piece[-1])
    assert run.pieces[piece_index].block == piece.block
    positions = np.concatenate([cursor.before, samples.position_mm])[-3:]
    last = Samples(samples.piece[-1:] * 0, samples.u[-1:], samples.position_mm[-1:], np.zeros(1))
    return Cursor(piece_index, float(samples.u[-1]), raw_s - s_cut, raw_v, history, positions, last, at_rest=False,
                  run_s_mm=cursor.run_s_mm + s_cut)


def is_straight(run: Run) -> bool:
    """A run of one straight block (a line: degree 1, two control points)."""
    return len(run.pieces) == 1 and run.pieces[0].curve.degree == 1 and len(run.pieces[0].curve.control_points) == 2


def straight_limits(direction: NDArray[np.float64], feed_mm_s: float, machine: MachineLimits) -> tuple[float, float]:
    """(V, A) along a line of unit ``direction``: the feed and A, and every axis' share of them."""
    v, a = feed_mm_s, machine.accel_mm_s2
    moving = np.abs(direction) > 1e-12
    if machine.axis_velocity_mm_s is not None:
        v = min(v, float(np.min(machine.axis_velocity_mm_s[moving] / np.abs(direction[moving]))))
    if machine.axis_accel_mm_s2 is not None:
        a = min(a, float(np.min(machine.axis_accel_mm_s2[moving] / np.abs(direction[moving]))))
    return v, a


def straight_run_plan(run: Run, cursor: Cursor, settings: PlanSettings) -> WindowPlan | None:
    """The time-optimal plan of a rest-to-rest run along one straight block (straight.py), to
    the machine's limits (the 1-D profile holds them exactly: only straight.ROUNDING_MARGIN
    for the rounding of third differences of large coordinates), verified like
    every window. None when the run is not one line, starts moving, is longer than one
    window (chunked planning keeps windows bounded) or fails the check (the general planner
    then takes it)."""
    if not cursor.at_rest or not is_straight(run):
        return None
    piece = run.pieces[0]
    grid = build_grid(run.pieces, settings.spacing_mm, settings.feed_step_s, MIN_SPACING_MM)
    if grid.length_mm > settings.window_mm or grid.length_mm <= 0.0:
        return None
    direction = grid.tangent[0]
    v, a = straight_limits(direction, piece.feed_mm_s, settings.machine)
    j = settings.machine.jerk_mm_s3
    share = straight.ROUNDING_MARGIN
    profile = straight.scurve(grid.length_mm, v * share, a * share, None if j is None else j * share)
    if profile.duration_s > MAX_WINDOW_CYCLES * settings.limits.period_s:
        return None
    s = straight.cycle_positions(profile, grid.length_mm, settings.limits.period_s)
    samples = sample_path(grid, s)
    planned_ds = s - np.concatenate([[s[0]], s[:-1]])
    before = cursor.before if len(cursor.before) else np.repeat(samples.position_mm[:1], 3, axis=0)
    after = np.repeat(samples.position_mm[-1:], 3, axis=0)
    result = check(grid, samples, s, planned_ds, settings.machine, before, after, cursor.previous)
    if result.violations():
        return None
    blocks = set_point_blocks((piece,), samples.piece, samples.u)
    return WindowPlan(samples, s, planned_ds, result, 0, True, None, blocks)


SHORT_RUN_SHARES = (1.0, 0.85, 0.7, 0.55)
SHORT_RUN_MAX_PIECES = 8
SHORT_RUN_GRID_POINTS = 400  # a short run gets at least this many grid points (plateau edges)


def short_run_plan(run: Run, cursor: Cursor, settings: PlanSettings, length_mm: float) -> WindowPlan | None:
    """The fastest plan of a short rest-to-rest run with the jerk filter, trying smaller raw
    accelerations A s with filter times tau_f s (same jerk A / tau_f): a move too short to
    reach A is faster with a shorter filter (within 0.2 % of ruckig on a 5 mm line instead of
    4.5 %). None for runs that are not short (longer than the stopping distance from the
    highest feed, or taking longer than twice the time to reach the feed and stop again) or
    that start moving."""
    if settings.tau_f <= 0 or not cursor.at_rest or len(run.pieces) > SHORT_RUN_MAX_PIECES:
        return None
    length = sum(coarse_lengths(p.curve, p.u_start, p.u_end)[1][-1] for p in run.pieces)
    if length > settings.stop_mm:
        return None
    a = settings.limits.max_accel_mm_s2
    short_s = 2.0 * (settings.max_feed_mm_s / a + 2.0 * settings.tau_f)
    best = None
    spacing = max(min(settings.spacing_mm, length / SHORT_RUN_GRID_POINTS), MIN_SPACING_MM)
    for share in SHORT_RUN_SHARES:
        trial = replace(settings, tau_f=settings.tau_f * share, tangential_share=share, spacing_mm=spacing)
        try:
            plan = plan_window(run, cursor, trial, length_mm)
        except (PlanningError, _WindowTooShort):
            continue
        if not plan.final or (share == 1.0 and len(plan.samples.u) * settings.limits.period_s > short_s):
            return None
        if best is None or len(plan.samples.u) < len(best.samples.u):
            best = plan
    return best


def merge_carry(a: Carry | None, b: Carry) -> Carry:
    """Repairs of two windows on one run-coordinate grid (the tighter of both everywhere)."""
    if a is None:
        return b
    s = np.union1d(a[0], b[0])
    caps = np.minimum(np.interp(s, a[0], a[1], left=NO_CAP, right=NO_CAP),
                      np.interp(s, b[0], b[1], left=NO_CAP, right=NO_CAP))
    scales = np.minimum(np.interp(s, a[0], a[2], left=1.0, right=1.0), np.interp(s, b[0], b[2], left=1.0, right=1.0))
    return s, caps, scales


MAX_FEED_HALVINGS = 16


@dataclass
class _Followup:
    """What plan_run plans after a run it had to give up on: (run, feed floor) pairs, in order."""

    runs: list[tuple[Run, float | None, str]] = field(default_factory=list)
    discarded: int = 0  # window plans thrown away so far (failed, too short, or a held-back window re-planned)

    def take_discarded(self) -> int:
        count, self.discarded = self.discarded, 0
        return count


FALLBACK_STOP = "stop"  # the held-back window ran to its own stop; the rest of its run starts from rest
FALLBACK_SPLIT = "split"  # a run failing from rest: an exact stop after its first block
FALLBACK_SLOWER = "slower"  # a single block failing from rest: half its feed


def plan_run(run: Run, settings: PlanSettings, before: NDArray[np.float64],
             cursor: Cursor | None = None) -> Iterator[WindowPlan]:
    """All windows of one run, to rest at its end; from rest at its start unless ``cursor`` says otherwise.

    One window is held back: when a window cannot be repaired (typically because the repair
    would have to start before its first set-point), the held-back window is planned again
    with twice the look-ahead, so it meets the trouble far enough ahead to slow down for it
    (at most MAX_BACKTRACKS times in a row). When that does not help either, the planner
    falls back to slower plans, verified like every other (a plan only trades motion time
    for existing): the held-back window runs to its own verified stop and the rest of the run
    starts from rest there; a run that fails from rest stops after its first block; a single
    block that fails from rest is planned at half its feed, down to 1/2**MAX_FEED_HALVINGS of
    it (then PlanningError). Every yielded plan carries the (sub-)run it belongs to."""
    todo: list[tuple[Run, Cursor | None, float | None, str]] = [(run, cursor, None, "")]
    discarded = 0
    while todo:
        part, start, floor, reason = todo.pop()
        followup = _Followup()
        for plan in run_windows(part, settings, before, start, floor, followup):
            plan.discarded, discarded = discarded + followup.take_discarded(), 0
            plan.run = plan.run or part
            plan.fallback, reason = reason, ""
            before = np.concatenate([before, plan.samples.position_mm])[-3:]
            yield plan
        discarded += followup.take_discarded()
        todo.extend((r, None, f, why) for r, f, why in reversed(followup.runs))


def run_windows(run: Run, settings: PlanSettings, before: NDArray[np.float64], cursor: Cursor | None,
                feed_floor_mm_s: float | None, followup: _Followup) -> Iterator[WindowPlan]:
    """The windows of one run (plan_run); where it gives up, the runs to plan instead go to ``followup``."""
    cursor = cursor if cursor is not None else Cursor(0, run.pieces[0].u_start, before=before)
    length = settings.window_mm
    line = straight_run_plan(run, cursor, settings)
    if line is not None:
        yield line
        return
    short = short_run_plan(run, cursor, settings, length)
    if short is not None:
        yield short
        return
    pending: WindowPlan | None = None
    pending_cursor = cursor
    backtracks = 0
    while True:
        try:
            plan = plan_window(run, cursor, settings, length)
        except _WindowTooShort:
            followup.discarded += 1
            length *= 2.0
            continue
        except PlanningError as error:
            followup.discarded += 1
            if pending is None:
                if not cursor.at_rest:
                    raise  # a running start (plan_from_state, resume): nothing committed to stop with
                followup.runs.extend(runs_from_rest(run, feed_floor_mm_s, error))
                return
            if backtracks < MAX_BACKTRACKS:
                backtracks += 1
                length *= 2.0
                followup.discarded += 1  # the held-back window's plan, or this re-plan of it
                try:
                    pending = plan_window(run, pending_cursor, settings, length)
                except (PlanningError, _WindowTooShort):
                    pass  # keep the held-back window as it was: it has a verified stop
                else:
                    if pending.final:
                        yield pending
                        return
                    cursor = pending.next_cursor()
                    continue
            stop = pending.verified_stop()
            yield stop
            followup.runs.extend((rest, None, FALLBACK_STOP) for rest in rest_after_stop(run, stop))
            return
        backtracks = 0
        if pending is not None:
            yield pending
        if plan.final:
            yield plan
            return
        pending, pending_cursor = plan, cursor
        cursor = plan.next_cursor()
        length = settings.window_mm


def rest_after_stop(run: Run, stop: WindowPlan) -> list[Run]:
    """The part of ``run`` after a window's stop (its last set-point, at rest), as a run from rest."""
    index = stop.start_piece + int(stop.samples.piece[-1])
    u = float(stop.samples.u[-1])
    piece = run.pieces[index]
    if u >= piece.u_end:
        rest = Run(run.pieces[index + 1:], run.junction_speed_mm_s[index + 1:])
    else:
        rest = Run((replace(piece, u_start=u),) + run.pieces[index + 1:], run.junction_speed_mm_s[index:])
    return [rest] if rest.pieces else []


def runs_from_rest(run: Run, feed_floor_mm_s: float | None,
                   error: PlanningError) -> list[tuple[Run, float | None, str]]:
    """What to plan instead of a run that cannot be planned from rest: the run to a stop
    before the block where it failed (failing_piece), then the rest from there; a single block
    at half its feed (raises ``error`` below the floor).

    Each part is shorter than the run, so this ends; a part failing in its first block stops
    after it. (Always stopping after the first block re-planned the whole rest of the run once
    per block when the failure was far ahead: grbl's braid at T = 1 ms, one window of ~2 m,
    stopped block by block for more than 10 minutes.)"""
    if len(run.pieces) > 1:
        k = failing_piece(run, error)
        return [(Run(run.pieces[:k], run.junction_speed_mm_s[:k - 1]), None, FALLBACK_SPLIT),
                (Run(run.pieces[k:], run.junction_speed_mm_s[k:]), None, "")]
    piece = run.pieces[0]
    floor = feed_floor_mm_s if feed_floor_mm_s is not None else piece.feed_mm_s / 2.0**MAX_FEED_HALVINGS
    if piece.feed_mm_s / 2.0 < floor:
        raise error
    return [(Run((piece.slower(0.5),), ()), floor, FALLBACK_SLOWER)]


def failing_piece(run: Run, error: PlanningError) -> int:
    """Index of the run's piece where ``error`` arose (the last piece starting at or before its
    block: a smoothed piece spans several blocks), at least 1: the cut of runs_from_rest."""
    if error.block is None:
        return 1
    blocks = np.array([p.block for p in run.pieces])
    return int(np.clip(np.searchsorted(blocks, error.block, side="right") - 1, 1, len(run.pieces) - 1))
