"""Speed limits along the path from every constraint at once, and the tangential
acceleration each point allows at a given speed.

All limits are planned to ``MARGIN`` of the machine's figures (the verify-and-repair loop
then checks the set-points against the full figures). With x = v^2, a_t = dv/dt, t the unit
tangent, c = x_ss the curvature vector and c' = x_sss:

- feed: v <= F (limits.feed_for of the block);
- chord error: a step of arc length dL where |x_ss| <= kappa stays within kappa dL^2 / 8
  of its chord, so dL <= sqrt(8 delta / kappa); v <= dL / T with kappa the largest curvature
  within one step either side (a sliding maximum over +-dL of the grid intervals' maxima,
  dL starting at F T, not the curvature at the point);
- axis velocity: |t_i| v <= vmax_i;
- resultant acceleration: a_t^2 + (|c| x)^2 <= A^2;
- axis acceleration: |t_i a_t + c_i x| <= amax_i;
- jerk (when J is set): x_sss v^3 + 3 c v a_t + t j dominate the path jerk, so
  v^3 (|c'| + |c|^2) <= JERK_SHARE J and 3 |c| v |a_t| <= JERK_SHARE J (each term its share,
  the verify-and-repair loop checks the sum); where the
  curvature vector jumps (knots of a degree-2 curve, a line meeting an arc) the second
  difference jumps within two cycles: |dc| v^2 / (2 T) <= J. The jerk filter gives the
  tangent j_t up to J wherever a_t changes by A; the normal jerk N = |3 c v a_t + c'_n v^3|
  (c'_n: c' less its tangent part) adds to it at right angles, so on curves the raw tangential
  acceleration starts at sqrt(1 - (N/J)^2) of A (tangential_jerk_share, never below
  MIN_TANGENTIAL_SHARE), N estimated at full A and the point's speed cap, then (planner,
  first round) at the speeds the scan planned.
The acceleration constraints are convex in (x, a_t), so the speeds at which some a_t is
admissible form an interval [0, x_max]: found by vectorised bisection.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.planning.lookahead.path import PathGrid, row_dots, row_max, row_norms

MARGIN = 0.995  # fraction of every machine limit the planner aims at
JERK_SHARE = 0.8  # share of J each of the path's own jerk terms may use on curves (repairs check the sum)
MIN_TANGENTIAL_SHARE = 0.4  # floor of tangential_jerk_share (repairs go lower where needed)
BISECTION_STEPS = 40
TINY = 1e-12


@dataclass(frozen=True)
class Caps:
    """The limits the planner aims at (machine limits x MARGIN). Units in the names."""

    period_s: float
    chord_error_mm: float
    accel_mm_s2: float
    jerk_mm_s3: float | None
    axis_velocity_mm_s: NDArray[np.float64] | None  # (3,) inf where not limited
    axis_accel_mm_s2: NDArray[np.float64] | None


def min_table(values: NDArray[np.float64], levels: int) -> NDArray[np.float64]:
    """Sparse table of minima: row j holds min(values[i : i + 2^j]) at i, padded with +inf."""
    n = len(values)
    table = np.full((max(levels, 1), n), np.inf)
    table[0] = values
    width = 1
    for j in range(1, levels):
        np.minimum(table[j - 1, : n - width], table[j - 1, width:], out=table[j, : n - width])
        width *= 2
    return table


_FLOOR_LOG2 = np.zeros(2, dtype=np.intp)  # floor(log2(w)) for w = 0 .. len - 1 (0 for w <= 1), grown on demand


def floor_log2(width: NDArray[np.intp]) -> NDArray[np.intp]:
    """floor(log2(max(width, 1))) of integer widths by a table lookup (np.log2 and floor cost
    ~10x a gather on thousands of values)."""
    global _FLOOR_LOG2
    table = _FLOOR_LOG2  # one reference: another thread may replace the module's table meanwhile
    top = int(width.max(initial=1))
    if top >= len(table):
        w = np.arange(max(2 * top, 1024))
        table = _FLOOR_LOG2 = np.floor(np.log2(np.maximum(w, 1))).astype(np.intp)
    return table.take(np.maximum(width, 1))


def table_min(table: NDArray[np.float64], lo: NDArray[np.intp], hi: NDArray[np.intp]) -> NDArray[np.float64]:
    """min(values[lo_k : hi_k + 1]) from a min_table deep enough for the spans: two gathers
    (from the flat table: one index instead of two)."""
    level = floor_log2(hi - lo + 1)
    row = level * table.shape[1]
    flat = table.reshape(-1)
    return np.minimum(flat.take(row + lo), flat.take(row + hi - (1 << level) + 1))


def range_min(values: NDArray[np.float64], lo: NDArray[np.intp], hi: NDArray[np.intp]) -> NDArray[np.float64]:
    """min(values[lo_k : hi_k + 1]) for every k, by a sparse table (O(N log N) once, O(1) per query)."""
    span = int(np.max(hi - lo + 1, initial=1))
    return table_min(min_table(values, int(np.floor(np.log2(max(span, 1)))) + 1), lo, hi)


def last_below(values: NDArray[np.float64], ends: NDArray[np.intp], levels: NDArray[np.float64]) -> NDArray[np.intp]:
    """For every k the largest j < ends[k] with values[j] < levels[k] (-1 where none), by
    binary lifting on a sparse table of minima: from ends[k], step back over every block of
    2^j points (largest first) whose minimum is not below the level."""
    depth = int(np.floor(np.log2(max(len(values), 1)))) + 1
    table = min_table(values, depth)
    start = ends.astype(np.intp)
    for j in range(depth - 1, -1, -1):
        back = start - (1 << j)
        clear = (back >= 0) & (table[j, np.maximum(back, 0)] >= levels)
        start = np.where(clear, back, start)
    return start - 1


SHORT_SPAN = 8  # windows of at most this many points: a direct minimum over the offsets


def window_min(values: NDArray[np.float64], lo: NDArray[np.intp], hi: NDArray[np.intp]) -> NDArray[np.float64]:
    """min(values[lo_k : hi_k + 1]) for every k: directly over the offsets when every window is
    short (steps and chord windows touch few grid points), else by range_min."""
    width = int((hi - lo).max(initial=0))
    if width > SHORT_SPAN:
        return range_min(values, lo, hi)
    out = values[lo]
    for offset in range(1, width + 1):
        out = np.minimum(out, values[np.minimum(lo + offset, hi)])
    return out


def sliding_min(s: NDArray[np.float64], values: NDArray[np.float64], half_width: NDArray[np.float64]) -> NDArray[np.float64]:
    """min of ``values`` over the grid points within +-half_width (in s) of each point."""
    lo = np.searchsorted(s, s - half_width, side="left")
    hi = np.searchsorted(s, s + half_width, side="right") - 1
    return window_min(values, lo, np.maximum(hi, lo))


def chord_step_mm(kappa: NDArray[np.float64], chord_mm: float) -> NDArray[np.float64]:
    """Longest step of a curve part with |x_ss| <= kappa whose chord error is at most chord_mm:
    kappa L^2 / 8 <= delta, L = sqrt(8 delta / kappa) (path.py; on a circle the sag of a step
    of arc L is rho (1 - cos(L / 2 rho)), at most this)."""
    return np.sqrt(8.0 * chord_mm / np.maximum(kappa, TINY))


def point_curvature_max(grid: PathGrid) -> NDArray[np.float64]:
    """Largest |x_ss| on the grid intervals either side of each point."""
    k = grid.kappa_max
    if len(k) == 0:
        return grid.kappa
    return np.maximum(np.concatenate([k[:1], k]), np.concatenate([k, k[-1:]]))


def chord_speed_limit(grid: PathGrid, caps: Caps) -> NDArray[np.float64]:
    """v <= dL(kappa_max over +-dL) / T, kappa_max the largest |x_ss| within a step either side."""
    kappa = point_curvature_max(grid)
    step = np.minimum(chord_step_mm(kappa, caps.chord_error_mm), grid.feed_mm_s * caps.period_s)
    for _ in range(3):  # the window depends on the step it limits: fixed-point passes
        kappa_max = -sliding_min(grid.s, -kappa, step)
        shorter = np.minimum(step, chord_step_mm(kappa_max, caps.chord_error_mm))
        if np.array_equal(shorter, step):  # a fixed point: further passes change nothing
            break
        step = shorter
    return step / caps.period_s


def axis_velocity_limit(grid: PathGrid, caps: Caps) -> NDArray[np.float64]:
    """v <= min_i vmax_i / |t_i|."""
    if caps.axis_velocity_mm_s is None:
        return np.full(len(grid), np.inf)
    with np.errstate(divide="ignore"):
        return -row_max(-caps.axis_velocity_mm_s[None, :] / np.abs(grid.tangent))


def jerk_speed_limit(grid: PathGrid, caps: Caps) -> NDArray[np.float64]:
    """v^3 (|c'| + |c|^2) <= JERK_SHARE J."""
    if caps.jerk_mm_s3 is None:
        return np.full(len(grid), np.inf)
    k = row_norms(grid.dcurv) + row_dots(grid.curv, grid.curv)
    with np.errstate(divide="ignore"):
        return np.cbrt(JERK_SHARE * caps.jerk_mm_s3 / k)


def tangential_jerk_share(grid: PathGrid, caps: Caps, tau_f: float, reach_mm: float,
                          speed_mm_s: NDArray[np.float64] | None = None,
                          static_mm_s: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Share of A for the raw tangential acceleration, per grid point, so that the filter's
    tangential jerk (share x J) and the path's normal jerk N = 3 |c| v A + |c'_n| v^3 (v the
    point's speed cap: feed, chord, jerk terms and A / |c|, or ``speed_mm_s`` where lower: the
    speeds a scan planned) add up to at most J: sqrt(1 - (N/J)^2), at least
    MIN_TANGENTIAL_SHARE; the smallest within the filter's reach (v tau_f + ``reach_mm``)
    either side. All ones without a jerk limit. ``static_mm_s``: static_speed_limit of the
    grid when the caller has it already."""
    if caps.jerk_mm_s3 is None or tau_f <= 0:
        return np.ones(len(grid))
    kappa = grid.kappa
    static = static_speed_limit(grid, caps) if static_mm_s is None else static_mm_s
    v = np.minimum(static, np.sqrt(caps.accel_mm_s2 / np.maximum(kappa, TINY)))
    if speed_mm_s is not None:
        v = np.minimum(v, speed_mm_s)
    normal = 3.0 * kappa * v * caps.accel_mm_s2 + grid.dcurv_normal * (v * v * v)
    share = np.maximum(np.sqrt(np.clip(1.0 - (normal / caps.jerk_mm_s3) ** 2, 0.0, 1.0)), MIN_TANGENTIAL_SHARE)
    return sliding_min(grid.s, share, v * tau_f + reach_mm)


@dataclass(eq=False)
class AccelBounds:
    """Admissible tangential acceleration [lo, hi] at each grid point for a given x = v^2."""

    tangent: NDArray[np.float64]
    curv: NDArray[np.float64]
    caps: Caps
    tangential_cap: NDArray[np.float64]  # (N,) |a_t| cap (A x the repair loop's local scale)
    kappa: NDArray[np.float64]  # (N,) |curv|

    @classmethod
    def for_grid(cls, grid: PathGrid, caps: Caps, scale: NDArray[np.float64]) -> "AccelBounds":
        return cls(grid.tangent, grid.curv, caps, caps.accel_mm_s2 * scale, grid.kappa)

    def subset(self, idx: slice | NDArray[np.intp]) -> "AccelBounds":
        """The bounds of the points ``idx`` (a slice gives views, no copies)."""
        return AccelBounds(self.tangent[idx], self.curv[idx], self.caps, self.tangential_cap[idx], self.kappa[idx])

    @cached_property
    def jerk_accel_numerator(self) -> NDArray[np.float64]:
        """JERK_SHARE J / (3 |c|) (inf on straight parts): 3 |c| v |a_t| <= JERK_SHARE J gives
        |a_t| <= this / v."""
        if self.caps.jerk_mm_s3 is None:
            return np.full(len(self.kappa), np.inf)
        with np.errstate(divide="ignore"):
            return JERK_SHARE * self.caps.jerk_mm_s3 / (3.0 * self.kappa)

    @cached_property
    def symmetric(self) -> bool:
        """lo = -hi at every speed: no axis acceleration limit shifts the admissible a_t."""
        return self.caps.axis_accel_mm_s2 is None or not bool(np.isfinite(self.caps.axis_accel_mm_s2).any())

    def tangential_room(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """hi of ``at`` where x is admissible (|c| x <= A), 0 where it is not: the resultant,
        tangential and jerk caps of |a_t| (axis limits aside). Enough for the scan's interval
        bounds, which clip at 0 (``at`` marks inadmissible points -inf and builds lo)."""
        kappa_x = self.kappa * x
        a = self.caps.accel_mm_s2
        hi = np.sqrt(np.maximum(a * a - kappa_x * kappa_x, 0.0))
        np.minimum(hi, self.tangential_cap, out=hi)
        if self.caps.jerk_mm_s3 is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                np.minimum(hi, self.jerk_accel_numerator / np.sqrt(x), out=hi)
        return hi

    def at(self, x: NDArray[np.float64], idx: slice | NDArray[np.intp] = slice(None)) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(lo, hi) of a_t at x (points ``idx``); lo > hi where x is not admissible."""
        t, c = self.tangent[idx], self.curv[idx]
        kappa_x = self.kappa[idx] * x
        a = self.caps.accel_mm_s2
        hi = np.minimum(np.sqrt(np.maximum(a * a - kappa_x * kappa_x, 0.0)), self.tangential_cap[idx])
        if self.caps.jerk_mm_s3 is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                hi = np.minimum(hi, self.jerk_accel_numerator[idx] / np.sqrt(x))
        hi[kappa_x > a] = -np.inf
        lo = -hi
        if self.caps.axis_accel_mm_s2 is not None:
            for i, amax in enumerate(self.caps.axis_accel_mm_s2):
                if not np.isfinite(amax):
                    continue
                ti, ci = t[:, i], c[:, i] * x
                moving = np.abs(ti) > TINY
                safe = np.where(moving, ti, 1.0)
                b1, b2 = (-amax - ci) / safe, (amax - ci) / safe
                lo = np.where(moving, np.maximum(lo, np.minimum(b1, b2)), np.where(np.abs(ci) > amax, np.inf, lo))
                hi = np.where(moving, np.minimum(hi, np.maximum(b1, b2)), hi)
        return lo, hi

    @property
    def speed_depends_on_scale(self) -> bool:
        """Whether max_speed_squared depends on the tangential cap: only through the axis
        acceleration limits (without them a_t = 0 decides, whatever the cap)."""
        return not self.symmetric

    def max_speed_squared(self, x_cap: NDArray[np.float64]) -> NDArray[np.float64]:
        """Largest x <= x_cap at which some a_t is admissible (feasible x form [0, x_max]).

        Without axis acceleration limits a_t = 0 is admissible exactly while |c| x <= A (the
        tangential and jerk caps are positive), so x_max = min(x_cap, NORMAL_SHARE A / |c|);
        with them, bisection below that. NORMAL_SHARE < 1 leaves sqrt(1 - 0.99^2) = 14 % of A
        for the tangent at the cap: where the curvature stays near its cap for long (short
        lines blended into a chain of near-constant curvature, blend.py) a cap with no
        tangential room at all made the scan's odd iterates (scan.py) climb out of a slow
        start by a little per round: grbl's HSM_test without a jerk limit planned its 200
        mm/s part at 20 mm/s (15.4 s instead of 3.6 s)."""
        x = np.array(x_cap, dtype=float)
        normal = NORMAL_SHARE * self.caps.accel_mm_s2
        if not self.speed_depends_on_scale:
            with np.errstate(divide="ignore"):
                return np.minimum(x, normal / self.kappa)
        lo, hi = self.at(x)
        bad = np.flatnonzero(~(lo <= hi))
        if len(bad) == 0:
            return x
        kappa = self.kappa[bad]
        top = np.minimum(x[bad], normal / np.maximum(kappa, TINY))
        bottom = np.zeros(len(bad))
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (bottom + top)
            l, h = self.at(mid, bad)
            ok = l <= h
            bottom = np.where(ok, mid, bottom)
            top = np.where(ok, top, mid)
        x[bad] = bottom
        return x


def curvature_jumps(grid: PathGrid) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(s, |c+ - c-|) at every place where the curvature vector jumps: interior knots of a
    piece (a degree-2 curve is only C1 there; path.py keeps the left limits) and junctions of
    pieces (a line meeting an arc)."""
    at_knot = row_norms(grid.curv - grid.curv_left)
    ends = np.flatnonzero(grid.junction)
    at_knot[ends + 1] = row_norms(grid.curv[ends + 1] - grid.curv[ends])
    jumps = np.flatnonzero(at_knot > 0)
    return grid.s[jumps], at_knot[jumps]


def curvature_jump_speed_limit(grid: PathGrid, caps: Caps) -> NDArray[np.float64]:
    """Where the curvature vector jumps by dc, the second difference of the set-points jumps by
    by |dc| v^2 T^2, shared between the two cycles around the step that crosses the jump:
    third difference / T^3 ~ |dc| v^2 / (2 T) <= J, applied within one step (F T) of the
    jump (the verify-and-repair loop checks what this estimate misses)."""
    if caps.jerk_mm_s3 is None:
        return np.full(len(grid), np.inf)
    s_jump, dc = curvature_jumps(grid)
    big = dc > TINY
    s_jump, dc = s_jump[big], dc[big]
    reach = float(grid.feed_mm_s.max()) * caps.period_s
    lo = np.searchsorted(grid.s, s_jump - reach)
    hi = np.searchsorted(grid.s, s_jump + reach) - 1  # the points in [s0 - reach, s0 + reach)
    near = hi >= lo
    return range_min_update(len(grid), lo[near], hi[near], np.sqrt(caps.jerk_mm_s3 * caps.period_s / dc[near]))


def static_speed_limit(grid: PathGrid, caps: Caps) -> NDArray[np.float64]:
    """Pointwise speed limit from feed, chord error, axis velocity and jerk (mm/s): the path's
    geometry and the caps only, so a window computes it once."""
    v = np.minimum(grid.feed_mm_s, chord_speed_limit(grid, caps))
    v = np.minimum(v, axis_velocity_limit(grid, caps))
    v = np.minimum(v, jerk_speed_limit(grid, caps))
    return np.minimum(v, curvature_jump_speed_limit(grid, caps))




def range_min_update(n: int, lo: NDArray[np.intp], hi: NDArray[np.intp],
                     values: NDArray[np.float64]) -> NDArray[np.float64]:
    """out[i] = min of values[k] over every k with lo_k <= i <= hi_k (inf where none): the
    sparse table of range_min run backwards. Each range is two blocks of 2^j points (j =
    floor(log2 of its length)); the blocks' minima are pushed down from the widest level,
    each block of 2^j into its two halves."""
    level = floor_log2(hi - lo + 1)
    levels = int(level.max(initial=0)) + 1
    table = np.full((levels, n), np.inf)
    flat = table.reshape(-1)
    np.minimum.at(flat, level * n + lo, values)
    np.minimum.at(flat, level * n + hi - (1 << level) + 1, values)
    for j in range(levels - 1, 0, -1):
        half = 1 << (j - 1)
        width = n - (1 << j) + 1  # blocks of 2^j that fit
        if width <= 0:
            continue
        np.minimum(table[j - 1, :width], table[j, :width], out=table[j - 1, :width])
        np.minimum(table[j - 1, half:half + width], table[j, :width], out=table[j - 1, half:half + width])
    return table[0]


NORMAL_SHARE = 0.99  # of A the normal acceleration may take at a speed cap (max_speed_squared)
DIP_LEVEL_RATIO = 1.5  # speed levels of widen_dips
DIP_HALF_TIME = 0.5  # a widened dip spans +-this x (its level x averaging time), out to grid points
DIP_WIDTH_FACTOR = 0.75  # a junction passed moving must keep a plateau of +-this x v tau >= a grid interval (runs.py)


def dip_levels(inner: NDArray[np.float64]) -> NDArray[np.float64]:
    """The geometric speed levels of widen_dips: from the lowest finite limit (at least 1e-3
    of the highest) up by DIP_LEVEL_RATIO, the last one the highest."""
    finite = inner[np.isfinite(inner)]
    top = float(finite.max())
    level = max(float(finite.min()), 1e-3 * top, 1e-9)
    levels = [level]
    while level < top:
        level = min(level * DIP_LEVEL_RATIO, top)
        levels.append(level)
    return np.array(levels)


def widen_dips(s: NDArray[np.float64], v: NDArray[np.float64], averaging_s: float,
               spreads: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """Spread every low speed limit v_j over +-DIP_HALF_TIME v_j tau around its point, out to the
    grid points at or beyond those ends (the raw profile only holds a plateau on grid points), so
    a moving average over tau seconds only ever sees the dip's own speed while it passes the
    dip: when the average s_f(t) = p, the raw positions of its window [t - tau, t] lie within
    +-v_j tau / 2 of p if the raw speed is at most v_j there (a window reaching further on one
    side, at a higher speed, would put its mean on that side), so the set-point's speed
    (s(t) - s(t - tau)) / tau <= v_j. Was +-0.75 v_j tau inside the grid points: the braid's
    loops held ~1.5x as long (issue 24).

    Done per speed band (L / DIP_LEVEL_RATIO, L] (geometric levels, dip_levels): the limits in
    a band spread over a fixed +-L tau / 2, at most DIP_LEVEL_RATIO x their own width (on the
    safe side); all bands at once by range_min_update. The two ends (the run's start and end
    states) are not dips and do not spread, nor do points outside ``spreads`` (the planner's
    points at their piece's feed: feed_plateaus spreads those exactly, without the bands'
    rounding up, to grid points placed at their ends)."""
    inner = v.copy()
    inner[0] = inner[-1] = np.inf
    if spreads is not None:
        inner[~spreads] = np.inf
    members = np.flatnonzero(np.isfinite(inner))
    if averaging_s <= 0 or len(members) == 0:
        return v
    levels = dip_levels(inner)
    band_level = levels[np.minimum(np.searchsorted(levels, inner[members], side="left"), len(levels) - 1)]
    half_width = DIP_HALF_TIME * band_level * averaging_s
    lo = np.maximum(np.searchsorted(s, s[members] - half_width, side="right") - 1, 0)
    hi = np.minimum(np.searchsorted(s, s[members] + half_width, side="left"), len(s) - 1)
    out = np.minimum(v, range_min_update(len(s), lo, hi, inner[members]))
    out[0], out[-1] = v[0], v[-1]
    return out


def feed_plateaus(s: NDArray[np.float64], piece: NDArray[np.int32], feed_mm_s: NDArray[np.float64],
                  plateau_s: float) -> NDArray[np.float64]:
    """Speed cap from the pieces' feeds: each piece's feed F (each part of one feed: a blend
    steps up at its middle, path.BlockPiece.feed_out_mm_s) over the piece and F x plateau_s
    beyond its ends, out to the grid points at or beyond those (path.build_grid puts one there).
    plateau_s = tau / 2 + T (PlanSettings.feed_plateau_s): as in widen_dips, the set-point's
    speed is the raw speed averaged over tau, and while the set-point is on the piece the
    window's raw positions lie within F tau / 2 of it; T more for the step that ends on the piece
    from up to F T before it. So no step ending on a piece runs above its feed. Exact, per
    piece, unlike widen_dips' bands: the feed is not checked per cycle (verify.py), every other
    limit is."""
    n = len(s)
    starts = np.flatnonzero(np.concatenate([[True], (piece[1:] != piece[:-1]) | (feed_mm_s[1:] != feed_mm_s[:-1])]))
    ends = np.concatenate([starts[1:] - 1, [n - 1]])
    feed = feed_mm_s[starts]
    if feed.min() == feed.max():  # one feed: every point is capped at it already
        return np.full(n, feed[0])
    half = feed * plateau_s
    lo = np.maximum(np.searchsorted(s, s[starts] - half, side="right") - 1, 0)
    hi = np.minimum(np.searchsorted(s, s[ends] + half, side="left"), n - 1)
    return range_min_update(n, lo, hi, feed)
