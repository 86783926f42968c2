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

import numpy as np
from numpy.typing import NDArray

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
        dt = np.diff(self.t)
        piece = self.s[:-1] * dt + self.v[:-1] * dt**2 / 2.0 + self.a * dt**3 / 6.0
        return np.concatenate([[0.0], np.cumsum(piece)])

    def locate(self, t: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.a) - 1)
        return k, t - self.t[k]

    def position(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        k, tau = self.locate(t)
        tau_in = np.clip(tau, 0.0, np.diff(self.t)[k])
        s = self.s[k] + self.v[k] * tau_in + self.a[k] * tau_in**2 / 2.0
        before = t < self.t[0]
        s = np.where(before, self.s[0] + self.v[0] * (t - self.t[0]), s)
        return np.where(t >= self.t[-1], self.s[-1] + self.v[-1] * (t - self.t[-1]), s)

    def integral(self, t: NDArray[np.float64], cumulative: NDArray[np.float64]) -> NDArray[np.float64]:
        """integral of s from t[0] to t (extended as in the class docstring)."""
        k, tau = self.locate(t)
        tau_in = np.clip(tau, 0.0, np.diff(self.t)[k])
        inside = cumulative[k] + self.s[k] * tau_in + self.v[k] * tau_in**2 / 2.0 + self.a[k] * tau_in**3 / 6.0
        dt0 = t - self.t[0]
        before = self.s[0] * dt0 + self.v[0] * dt0**2 / 2.0
        dte = t - self.t[-1]
        after = cumulative[-1] + self.s[-1] * dte + self.v[-1] * dte**2 / 2.0
        return np.where(t < self.t[0], before, np.where(t >= self.t[-1], after, inside))


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


PLATEAU_SEARCH_STEPS = 40
PLATEAU_MARGIN = 1.02  # plateaus last 2 % longer than tau_f (the grid is not the time axis)


@dataclass(frozen=True)
class PeakSides:
    """Running minima of x = v^2 going out from a peak to the left and to the right (both
    start at the peak): the first point below a level either side is one binary search."""

    peak: int
    left_min: NDArray[np.float64]  # left_min[k] = min(x[peak - k .. peak])
    right_min: NDArray[np.float64]  # right_min[k] = min(x[peak .. peak + k])

    @classmethod
    def of(cls, x: NDArray[np.float64], peak: int) -> "PeakSides":
        return cls(peak, -np.minimum.accumulate(x[peak::-1]), -np.minimum.accumulate(x[peak:]))


def superlevel_width(s: NDArray[np.float64], x: NDArray[np.float64], sides: PeakSides, level: float) -> float:
    """Length of the stretch around the peak where x >= level (linear crossings), for
    level <= x[peak]: from the last point below it on the left to the first on the right
    (the same points as scanning x, found by binary search in the negated running minima)."""
    peak = sides.peak
    k = int(sides.left_min.searchsorted(-level, side="right"))
    if k < len(sides.left_min):
        j = peak - k
        left = s[j] + (level - x[j]) / (x[j + 1] - x[j]) * (s[j + 1] - s[j])
    else:
        left = s[0]
    k = int(sides.right_min.searchsorted(-level, side="right"))
    if k < len(sides.right_min):
        j = peak + k
        right = s[j - 1] + (x[j - 1] - level) / (x[j - 1] - x[j]) * (s[j] - s[j - 1])
    else:
        right = s[-1]
    return right - left


def plateau_level(s: NDArray[np.float64], x: NDArray[np.float64], peak: int, tau_f: float,
                  allowance_mm: float) -> float:
    """Highest x = v^2 whose superlevel stretch around ``peak`` is PLATEAU_MARGIN v tau_f +
    allowance long (bisection)."""
    sides = PeakSides.of(x, peak)
    lo, hi = 0.0, float(x[peak])
    for _ in range(PLATEAU_SEARCH_STEPS):
        mid = 0.5 * (lo + hi)
        if superlevel_width(s, x, sides, mid) >= PLATEAU_MARGIN * np.sqrt(mid) * tau_f + allowance_mm:
            lo = mid
        else:
            hi = mid
    return lo


def top_starts(x: NDArray[np.float64], peaks: NDArray[np.intp]) -> NDArray[np.intp]:
    """First grid point of the flat top that ends at each peak (the peak itself when it is sharp)."""
    starts = peaks.copy()
    for n, peak in enumerate(peaks):
        level = x[peak] * (1.0 - 1e-12)
        below = np.flatnonzero(x[:peak] < level)
        starts[n] = below[-1] + 1 if len(below) else 0
    return starts


def valleys_around(x: NDArray[np.float64], peak: int) -> tuple[int, int]:
    """Indices of the lowest points reached going down from ``peak`` (over its flat top) to
    either side: the extent of this one peak."""
    left = peak
    while left > 0 and x[left - 1] <= x[left]:
        left -= 1
    right = peak
    while right + 1 < len(x) and x[right + 1] <= x[right]:
        right += 1
    return left, right


def peak_plateau_caps(s: NDArray[np.float64], x: NDArray[np.float64], tau_f: float,
                      jerk: float) -> NDArray[np.float64] | None:
    """Caps (x = v^2) that cut every sharp speed peak of the raw profile to a plateau.

    A peak is sharp when the filtered jerk across it, (a(t_p - tau/2) - a(t_p + tau/2)) / tau,
    exceeds J. Its plateau level v is the highest at which the stretch with speed >= v is at
    least v tau long (so the raw motion holds that speed for tau): found by bisection. None when
    no peak is sharp."""
    inner = np.flatnonzero((x[1:-1] >= x[:-2]) & (x[1:-1] > x[2:]) & (x[1:-1] > 0)) + 1
    if len(inner) == 0:
        return None
    raw = raw_profile(s, x)
    t_peak = 0.5 * (np.interp(s[top_starts(x, inner)], raw.s, raw.t) + np.interp(s[inner], raw.s, raw.t))
    k_before, _ = raw.locate(t_peak - tau_f / 2.0)
    k_after, _ = raw.locate(t_peak + tau_f / 2.0)
    sharp = inner[(raw.a[k_before] - raw.a[k_after]) / tau_f > jerk]
    if len(sharp) == 0:
        return None
    caps = np.full(len(s), np.inf)
    spacing = float(np.diff(s).max())  # the cap only acts on grid points: allow one interval each side
    for peak in sharp:
        lo = plateau_level(s, x, peak, tau_f, 2.0 * spacing)
        if lo <= 0.0:  # a move shorter than two grid intervals: no allowance for the grid
            lo = plateau_level(s, x, peak, tau_f, 0.0)
        left, right = valleys_around(x, peak)
        near = np.zeros(len(s), dtype=bool)
        near[left:right + 1] = True  # this peak only: a low plateau must not cap its neighbours
        caps[near & (x > lo)] = np.minimum(caps[near & (x > lo)], lo)
    return caps
