"""Motion in time: the acceleration-limited profile as constant-acceleration pieces, and its
jerk-limited version by a moving average in time.

Raw profile: on grid interval k (length ds_k) the scan gives x_k = v_k^2 at both ends, so
the acceleration is a_k = (x_{k+1} - x_k) / (2 ds_k) and the time dt_k = 2 ds_k / (v_k + v_{k+1});
s(t) = s_k + v_k tau + a_k tau^2 / 2 on the piece.

Jerk limit (S-curve): the commanded position is the moving average of the raw position
over the last tau_f = A / J seconds,

  s_f(t) = (1 / tau_f) * integral_{t - tau_f}^{t} s(t') dt'
  =>  v_f = (s(t) - s(t - tau_f)) / tau_f,  a_f = (v(t) - v(t - tau_f)) / tau_f,
      j_f = (a(t) - a(t - tau_f)) / tau_f,

so |a_f| <= max |a| and the tangential jerk is at most (change of a within tau_f) / tau_f:
a change of A (start or end of an acceleration) gives exactly J. Where the raw profile goes
straight from accelerating to braking (a short move, a peak between two slow-downs) the
change is up to 2A: such peaks are cut to a plateau lasting tau_f (peak_plateau_caps). On a straight
rest-to-rest move with a cruise this is the time-optimal 7-phase S-curve (duration
D/V + V/A + A/J). Speed dips are widened to plateaus (speed_limits.widen_dips) so the
average never runs through a V-shaped dip. The integral of s is evaluated exactly from the
pieces (cumulative sum of per-piece integrals), relative to the window's own origin.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.planning.lookahead.speed_limits import last_below, range_min
from nurbsmotion.planning.lookahead.search import search_sorted

MIN_SPEED = 1e-9  # mm/s, keeps the time of an interval between two stops finite


@dataclass(eq=False)
class RawProfile:
    """Constant-acceleration pieces; before t[0] the motion continues at speed v[0] (history
    pieces are prepended for a running start); after t[-1] it rests at s[-1] (v[-1] = 0)."""

    t: NDArray[np.float64]  # (K+1,) piece start times, t[-1] the end
    s: NDArray[np.float64]  # (K+1,)
    v: NDArray[np.float64]  # (K+1,)
    a: NDArray[np.float64]  # (K,)

    @property
    def end_time_s(self) -> float:
        return float(self.t[-1])

    @property
    def integrals(self) -> NDArray[np.float64]:
        """integral of s from t[0] to t[k] for every k."""
        dt = self.dt
        piece = dt * (self.s[:-1] + dt * (self.v[:-1] / 2.0 + dt * (self.a / 6.0)))
        out = np.empty(len(self.t))
        out[0] = 0.0
        np.cumsum(piece, out=out[1:])
        return out

    @cached_property
    def dt(self) -> NDArray[np.float64]:
        """(K,) piece durations (the pieces never change after construction)."""
        return self.t[1:] - self.t[:-1]

    def locate(self, t: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        k = np.clip(search_sorted(self.t, t, side="right") - 1, 0, len(self.a) - 1)
        return k, t - self.t[k]

    def position(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        k, tau = self.locate(t)
        tau_in = np.clip(tau, 0.0, self.dt[k])
        s = self.s[k] + self.v[k] * tau_in + self.a[k] * tau_in**2 / 2.0
        before = t < self.t[0]
        s = np.where(before, self.s[0] + self.v[0] * (t - self.t[0]), s)
        return np.where(t >= self.t[-1], self.s[-1] + self.v[-1] * (t - self.t[-1]), s)

    def integral(self, t: NDArray[np.float64], cumulative: NDArray[np.float64]) -> NDArray[np.float64]:
        """integral of s from t[0] to t (extended as in the class docstring): on the piece k
        holding t, cumulative[k] + s_k tau + v_k tau^2 / 2 + a_k tau^3 / 6 (Horner)."""
        k, tau = self.locate(t)
        np.clip(tau, 0.0, self.dt[k], out=tau)
        out = cumulative[k] + tau * (self.s[k] + tau * (self.v[k] / 2.0 + tau * (self.a[k] / 6.0)))
        before = np.flatnonzero(t < self.t[0])  # outside the pieces (few points): the straight extensions
        if len(before):
            dt0 = t[before] - self.t[0]
            out[before] = self.s[0] * dt0 + self.v[0] * dt0 * dt0 / 2.0
        after = np.flatnonzero(t >= self.t[-1])
        if len(after):
            dte = t[after] - self.t[-1]
            out[after] = cumulative[-1] + self.s[-1] * dte + self.v[-1] * dte * dte / 2.0
        return out


def raw_profile(s: NDArray[np.float64], x: NDArray[np.float64], t0: float = 0.0) -> RawProfile:
    """Pieces of the scan result (grid s, x = v^2); zero-length intervals are dropped."""
    keep = np.concatenate([[True], np.diff(s) > 0])
    s, x = s[keep], x[keep]
    v = np.sqrt(np.maximum(x, 0.0))
    ds = np.diff(s)
    a = (v[1:] ** 2 - v[:-1] ** 2) / (2.0 * ds)
    dt = 2.0 * ds / np.maximum(v[1:] + v[:-1], MIN_SPEED)
    return RawProfile(t=t0 + np.concatenate([[0.0], np.cumsum(dt)]), s=s, v=v, a=a)


def filtered_position(raw: RawProfile, t: NDArray[np.float64], tau_f: float) -> NDArray[np.float64]:
    """s_f(t): the raw position averaged over [t - tau_f, t] (tau_f = 0: the raw position)."""
    if tau_f <= 0:
        return raw.position(t)
    cumulative = raw.integrals
    return (raw.integral(t, cumulative) - raw.integral(t - tau_f, cumulative)) / tau_f


def prepend_history(history: RawProfile, raw: RawProfile) -> RawProfile:
    """One profile: ``history`` pieces (ending at raw.t[0], raw.s[0]) followed by ``raw``."""
    return RawProfile(t=np.concatenate([history.t[:-1], raw.t]), s=np.concatenate([history.s[:-1], raw.s]),
                      v=np.concatenate([history.v[:-1], raw.v]), a=np.concatenate([history.a, raw.a]))


def history_before(raw: RawProfile, t_cut: float, span_s: float) -> RawProfile:
    """The pieces of ``raw`` covering [t_cut - span_s, t_cut], cut exactly at t_cut."""
    k_at_cut, tau_at_cut = raw.locate(np.array([t_cut]))
    k_end, tau = int(k_at_cut[0]), float(tau_at_cut[0])
    k_start = int(np.clip(np.searchsorted(raw.t, t_cut - span_s, side="right") - 1, 0, k_end))
    s_cut = float(raw.position(np.array([t_cut]))[0])
    v_cut = float(raw.v[k_end] + raw.a[k_end] * tau)
    return RawProfile(t=np.append(raw.t[k_start:k_end + 1], t_cut), s=np.append(raw.s[k_start:k_end + 1], s_cut),
                      v=np.append(raw.v[k_start:k_end + 1], v_cut), a=raw.a[k_start:k_end + 1].copy())


def shifted(raw: RawProfile, dt: float, ds: float) -> RawProfile:
    """The same profile with times and positions moved by (dt, ds)."""
    return RawProfile(t=raw.t + dt, s=raw.s + ds, v=raw.v, a=raw.a)


def cycle_times(duration_s: float, period_s: float) -> NDArray[np.float64]:
    """Sampling times of a rest-to-rest motion stretched minimally to a whole number of cycles:
    n = ceil(D / T) cycles, t_i = i T D / (n T), so the last sample is the end (at rest).
    Scaling time by k = nT/D >= 1 divides v by k, a by k^2 and j by k^3: every limit still holds."""
    cycles = max(int(np.ceil(duration_s / period_s - 1e-9)), 1)
    return np.arange(cycles + 1, dtype=np.float64) * (duration_s / cycles)


def warped_cycle_times(duration_s: float, period_s: float) -> NDArray[np.float64]:
    """Sampling times of a motion that starts moving (a running start): n = ceil(D / T) cycles
    of T, read through the time warp phi(t) = t - eps * n T * B(t / nT), B(r) = r^3 - r^4/2
    (B(0) = B'(0) = B''(0) = 0: speed and acceleration stay continuous at the start),
    eps chosen so that phi(nT) = D: eps = 2 (nT - D) / nT < 2 T / nT, and phi' = 1 - eps B'
    lies in [1 - eps, 1]: the motion is only ever slowed slightly."""
    cycles = max(int(np.ceil(duration_s / period_s - 1e-9)), 1)
    total = cycles * period_s
    eps = 2.0 * (total - duration_s) / total
    r = np.arange(cycles + 1) / cycles
    times = total * (r - eps * (r**3 - r**4 / 2.0))
    times[-1] = duration_s
    return times


PLATEAU_MARGIN = 1.02  # plateaus last 2 % longer than tau_f (the grid is not the time axis)


@dataclass(frozen=True)
class PeakSides:
    """Running minima of x = v^2 going out from each of several peaks, to the left and to the
    right (row i: peak i; column k: k points out), as far as any superlevel stretch can
    matter: a stretch reaching past the columns is wider than any plateau asked for, and
    then counts as reaching the columns' end (the width test gives the same answer)."""

    peaks: NDArray[np.intp]
    left: NDArray[np.intp]  # (n, m) grid index k points left of the peak (clipped at 0)
    right: NDArray[np.intp]  # (n, m) grid index k points right of the peak (clipped at the end)
    left_min: NDArray[np.float64]  # (n, m) min(x[peak - k .. peak]); +inf past the grid's start
    right_min: NDArray[np.float64]  # (n, m) min(x[peak .. peak + k]); +inf past its end

    @classmethod
    def of(cls, s: NDArray[np.float64], x: NDArray[np.float64], peaks: NDArray[np.intp],
           reach_mm: NDArray[np.float64]) -> "PeakSides":
        """Columns reaching at least ``reach_mm`` (per peak) either side of every peak."""
        lo = np.searchsorted(s, s[peaks] - reach_mm, side="left")
        hi = np.searchsorted(s, s[peaks] + reach_mm, side="right")
        m = int(max((peaks - lo).max(initial=0), (hi - peaks).max(initial=0))) + 2
        offsets = np.arange(m)
        left = peaks[:, None] - offsets[None, :]
        right = peaks[:, None] + offsets[None, :]
        left_x = np.where(left >= 0, x[np.maximum(left, 0)], np.inf)
        right_x = np.where(right < len(x), x[np.minimum(right, len(x) - 1)], np.inf)
        return cls(peaks, np.maximum(left, 0), np.minimum(right, len(x) - 1),
                   np.minimum.accumulate(left_x, axis=1), np.minimum.accumulate(right_x, axis=1))


ROW_SEARCH_MIN_LEVELS = 8  # from this many levels per peak, a bisection per row beats the full comparison


def count_at_or_above(running_min: NDArray[np.float64], level: NDArray[np.float64]) -> NDArray[np.intp]:
    """#{j: running_min[i, j] >= level[i, k]} for every peak i and level k: the running
    minima do not increase along a row, so with many levels one bisection per row (of the
    negated row, non-decreasing) instead of comparing every level with every column."""
    if level.shape[1] < ROW_SEARCH_MIN_LEVELS:
        return np.count_nonzero(running_min[:, None, :] >= level[:, :, None], axis=2)
    out = np.empty(level.shape, dtype=np.intp)
    rising, below = -running_min, -level
    for i in range(len(level)):
        out[i] = np.searchsorted(rising[i], below[i], side="right")
    return out


def superlevel_line(s: NDArray[np.float64], x: NDArray[np.float64], sides: PeakSides,
                    level: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Length of the stretch around every peak where x >= level (linear crossings), for
    level <= x[peak] (``level``: (n,) or (n, K), row i for peak i), as A + B level: from the
    last point below the level on the left to the first on the right (the running minima count
    the points at or above it; past the columns or the grid the stretch ends at the last
    column). A and B stay the same while the level stays between two running-minimum values
    (the same grid intervals are crossed): the width is linear in the level there."""
    level = np.asarray(level, dtype=float)
    flat = level.ndim == 1
    lv = level[:, None] if flat else level
    m = sides.left_min.shape[1]
    k = count_at_or_above(sides.left_min, lv)
    j = np.take_along_axis(sides.left, np.minimum(k, m - 1), axis=1)
    inside = (k < m) & (j < sides.peaks[:, None])
    jn = np.minimum(j + 1, len(x) - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope_left = np.where(inside, (s[jn] - s[j]) / (x[jn] - x[j]), 0.0)  # left = s_j + (L - x_j) slope
    k = count_at_or_above(sides.right_min, lv)
    j2 = np.take_along_axis(sides.right, np.minimum(k, m - 1), axis=1)
    inside = (k < m) & (j2 > sides.peaks[:, None])
    jp = np.maximum(j2 - 1, 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope_right = np.where(inside, (s[j2] - s[jp]) / (x[jp] - x[j2]), 0.0)  # right = s_jp + (x_jp - L) slope
    right_at_0 = np.where(inside, s[jp] + x[jp] * slope_right, s[j2])
    left_at_0 = s[j] - x[j] * slope_left
    width_0, slope = right_at_0 - left_at_0, -(slope_left + slope_right)
    return (width_0[:, 0], slope[:, 0]) if flat else (width_0, slope)


def plateau_levels(s: NDArray[np.float64], x: NDArray[np.float64], peaks: NDArray[np.intp], tau_f: float,
                   allowance_mm: float) -> NDArray[np.float64]:
    """Highest x = v^2 of every peak whose superlevel stretch around it is at least
    c sqrt(x) + d long (c = PLATEAU_MARGIN tau_f, d = ``allowance_mm``), all peaks at once.

    The width is tested at every running-minimum value (where its slope changes): the answer
    lies between the highest level that passes and the next one; there the width is A + B x
    (superlevel_line), so with q = sqrt(x): B q^2 - c q + (A - d) = 0,
    q = 2 (A - d) / (c + sqrt(c^2 - 4 B (A - d))) (B <= 0). 0 where no level passes."""
    c = PLATEAU_MARGIN * tau_f
    top = x[peaks].astype(float)
    sides = PeakSides.of(s, x, peaks, c * np.sqrt(top) + allowance_mm)
    candidates = np.concatenate([np.zeros((len(peaks), 1)), sides.left_min, sides.right_min], axis=1)
    candidates = np.sort(np.minimum(candidates, top[:, None]), axis=1)
    width_0, slope = superlevel_line(s, x, sides, candidates)
    passes = width_0 + slope * candidates >= c * np.sqrt(candidates) + allowance_mm
    count = candidates.shape[1]
    first_fail = np.where(passes.all(axis=1), count, np.argmin(passes, axis=1))
    rows = np.arange(len(peaks))
    last_ok = candidates[rows, np.maximum(first_fail - 1, 0)]
    fail = candidates[rows, np.minimum(first_fail, count - 1)]
    width_0, slope = superlevel_line(s, x, sides, 0.5 * (last_ok + fail))
    excess = np.maximum(width_0 - allowance_mm, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = 2.0 * excess / (c + np.sqrt(np.maximum(c * c - 4.0 * slope * excess, 0.0)))
    level = np.clip(np.nan_to_num(q * q), last_ok, fail)
    # the width drops where the level passes a running minimum: the last passing candidate
    # itself is the answer when the line already fails just above it
    level = np.where(width_0 + slope * last_ok < c * np.sqrt(last_ok) + allowance_mm, last_ok, level)
    level = np.where(first_fail == count, top, level)
    return np.where(first_fail == 0, 0.0, level)


def top_starts(x: NDArray[np.float64], peaks: NDArray[np.intp]) -> NDArray[np.intp]:
    """First grid point of the flat top that ends at each peak (the peak itself when it is
    sharp): one past the last point before it below x[peak] (1 - 1e-12). Usually the start
    of the run of values equal to x[peak] (a capped top); searched (last_below) only where
    the point before that run is not below the level."""
    level = x[peaks] * (1.0 - 1e-12)
    changes = np.concatenate([[True], x[1:] != x[:-1]])
    run_start = np.maximum.accumulate(np.where(changes, np.arange(len(x)), 0))
    starts = run_start[peaks]
    other = np.flatnonzero((starts > 0) & (x[np.maximum(starts - 1, 0)] >= level))
    if len(other):
        starts[other] = last_below(x, peaks[other], level[other]) + 1
    return starts


def valleys_around(x: NDArray[np.float64], peaks: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Indices of the lowest points reached going down from every peak (over its flat top) to
    either side: the extent of each peak (the first point, going out, where x rises again)."""
    n = len(x)
    rises_left = np.concatenate([[True], x[:-1] > x[1:]])  # at i: going left from i, x[i-1] > x[i] stops
    left_stop = np.maximum.accumulate(np.where(rises_left, np.arange(n), 0))
    rises_right = np.concatenate([x[1:] > x[:-1], [True]])  # at i: x[i+1] > x[i] stops
    right_stop = np.minimum.accumulate(np.where(rises_right, np.arange(n), n - 1)[::-1])[::-1]
    return left_stop[peaks], right_stop[peaks]


def peak_plateau_caps(s: NDArray[np.float64], x: NDArray[np.float64], tau_f: float, jerk: float,
                      curvature_sq: NDArray[np.float64] | None = None,
                      first_peak: int = 0) -> NDArray[np.float64] | None:
    """Caps (x = v^2) that cut every sharp speed peak of the raw profile to a plateau.

    A peak is sharp when the filtered jerk across it, (a(t_p - tau/2) - a(t_p + tau/2)) / tau,
    plus the path's own tangential jerk there exceeds J: on a curve the set-points' jerk along
    the tangent is j_t - |c|^2 v^3 (d/dt of the normal acceleration |c| v^2 turns the
    curvature vector), which adds to the braking side of the peak; ``curvature_sq`` is |c|^2
    at every point of ``s`` (the largest within v tau_f of the peak counts). Its plateau level
    v is the highest at which the stretch with speed >= v is at least v tau long (so the raw
    motion holds that speed for tau): plateau_levels. None when no peak is sharp.

    Points before ``first_peak`` are history (motion already committed, history_peak_caps):
    they count for the plateaus' widths but their own peaks are not capped again, and the
    grid allowance is taken from the points from ``first_peak`` on."""
    inner = np.flatnonzero((x[1:-1] >= x[:-2]) & (x[1:-1] > x[2:]) & (x[1:-1] > 0)) + 1
    inner = inner[inner >= first_peak]
    if len(inner) == 0:
        return None
    raw = raw_profile(s, x)
    t_peak = 0.5 * (np.interp(s[top_starts(x, inner)], raw.s, raw.t) + np.interp(s[inner], raw.s, raw.t))
    k_before, _ = raw.locate(t_peak - tau_f / 2.0)
    k_after, _ = raw.locate(t_peak + tau_f / 2.0)
    budget = np.full(len(inner), jerk)
    if curvature_sq is not None:
        v_peak = np.sqrt(x[inner])
        lo = np.searchsorted(s, s[inner] - v_peak * tau_f, side="left")
        hi = np.maximum(np.searchsorted(s, s[inner] + v_peak * tau_f, side="right") - 1, lo)
        budget -= -range_min(-curvature_sq, lo, hi) * v_peak**3
    sharp = inner[(raw.a[k_before] - raw.a[k_after]) / tau_f > budget]
    if len(sharp) == 0:
        return None
    spacing = float(np.diff(s[first_peak:]).max())  # the cap only acts on grid points: allow one interval each side
    level = plateau_levels(s, x, sharp, tau_f, 2.0 * spacing)
    short = level <= 0.0  # a move shorter than two grid intervals: no allowance for the grid
    if short.any():
        level[short] = plateau_levels(s, x, sharp[short], tau_f, 0.0)
    left, right = valleys_around(x, sharp)
    # each peak caps its own extent only: a low plateau must not cap its neighbours
    counts = right - left + 1
    index = np.repeat(left - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
    cap = np.repeat(level, counts)
    over = x[index] > cap
    caps = np.full(len(s), np.inf)
    np.minimum.at(caps, index[over], cap[over])
    return caps


def history_peak_caps(s: NDArray[np.float64], x: NDArray[np.float64], tau_f: float, jerk: float,
                      curvature_sq: NDArray[np.float64], history: RawProfile | None) -> NDArray[np.float64] | None:
    """peak_plateau_caps of a window's raw profile (s, x) that starts moving, with the raw
    motion before its start (``history``, ending at s[0]) in front: a peak just after the
    start is then measured with the stretch before it. Without it the stretch would end at
    the window's start, the plateau come out below the start speed, and the scan would lower
    the start speed itself (a jump of the raw speed at the join: up to 2-3 J on the first
    cycles). The history's curvature is taken as the start's (it only widens the budget test
    of peaks within v tau_f of the start)."""
    if history is None or len(history.s) < 2:
        return peak_plateau_caps(s, x, tau_f, jerk, curvature_sq)
    before = history.s[:-1] < s[0] - 1e-12
    h = int(np.count_nonzero(before))
    s_all = np.concatenate([history.s[:-1][before], s])
    x_all = np.concatenate([history.v[:-1][before] ** 2, x])
    curvature_all = np.concatenate([np.full(h, curvature_sq[0]), curvature_sq])
    caps = peak_plateau_caps(s_all, x_all, tau_f, jerk, curvature_all, first_peak=h)
    return None if caps is None else caps[h:]
