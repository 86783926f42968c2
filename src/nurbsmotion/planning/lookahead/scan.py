"""Bidirectional scan in x = v^2 over the whole grid (Klipper/TOPP style), vectorised.

With a constant tangential acceleration a_k on interval k (length ds_k), x changes by
2 a_k ds_k. The backward pass (decelerations, from the end) and the forward pass
(accelerations, from the start) have closed forms:

  forward:  x_i = C_i + min_{j<=i} (m_j - C_j),   C_i = sum_{k<i} 2 hi_k ds_k
  backward: x_i = min_{j>=i} (m_j + E_j) - E_i,   E_i = sum_{k<i} 2 (-lo_k) ds_k

(m the speed cap), i.e. a cumulative sum and a running minimum. The admissible a_t depends
on the speed (resultant and axis accelerations), so the passes are repeated with the bounds
evaluated at the previous result; the verify-and-repair loop checks what remains.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.planning.lookahead.speed_limits import AccelBounds

SCAN_ROUNDS = 3  # at least
SCAN_ROUNDS_MAX = 41  # odd: the result is an odd iterate (see speed_profile)
SCAN_CONVERGED = 1e-3  # relative change of x = v^2 between consecutive odd iterates


def climb(accel: NDArray[np.float64], ds2: NDArray[np.float64]) -> NDArray[np.float64]:
    """C_i = sum_{k<i} 2 accel_k ds_k (``ds2`` = 2 ds): the largest rise of x from point 0 to i."""
    c = np.empty(len(accel) + 1)
    c[0] = 0.0
    np.cumsum(accel * ds2, out=c[1:])
    return c


def forward_pass(cap: NDArray[np.float64], c: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest x <= cap reachable from x_0 = cap_0 with x_{i+1} <= x_i + 2 accel_i ds_i
    (``c`` = climb(accel, 2 ds))."""
    return c + np.minimum.accumulate(cap - c)


def backward_pass(cap: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest x <= cap from which x_{i} <= x_{i+1} + 2 decel_i ds_i reaches the end cap
    (``e`` = climb(decel, 2 ds))."""
    return np.minimum.accumulate((cap + e)[::-1])[::-1] - e


def interval_bounds(bounds: AccelBounds, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Deceleration and acceleration magnitudes usable on each interval: the tighter of its two
    ends (clipped at 0: an inadmissible end, -inf in ``at``, gives 0 like any end without room)."""
    if bounds.symmetric:
        hi = bounds.tangential_room(x)
        accel = np.minimum(hi[:-1], hi[1:])
        return np.maximum(accel, 0.0, out=accel), accel
    lo, hi = bounds.at(x)
    accel = np.maximum(np.minimum(hi[:-1], hi[1:]), 0.0)
    if bounds.symmetric:
        return accel, accel
    decel = np.minimum(-lo[:-1], -lo[1:])
    return np.maximum(decel, 0.0), accel


def speed_profile(s: NDArray[np.float64], cap: NDArray[np.float64], bounds: AccelBounds) -> NDArray[np.float64]:
    """x = v^2 at every grid point: under ``cap`` (x), decelerating into and accelerating out
    of every limit within the admissible tangential acceleration. cap[0] and cap[-1] carry
    the start and end speeds.

    The admissible acceleration shrinks as the speed grows, so the scan with the bounds
    evaluated at a profile y, F(y), is decreasing in y, and the time-optimal profile x* is
    its fixed point. From y_0 = cap >= x*, the iterates alternate around it: the odd ones
    x_1 <= x_3 <= ... <= x* (each scanned with the bounds at a faster profile: admissible
    at its own speeds), the even ones above. The result is an odd iterate, taken once two
    consecutive odd iterates differ by at most SCAN_CONVERGED of the top speed^2 (at most
    SCAN_ROUNDS_MAX rounds): near a curvature peak, where the path's own acceleration leaves
    little to brake with, three rounds stay up to 7 % below x*."""
    ds2 = 2.0 * np.diff(s)  # 2 a ds = a (2 ds) exactly: doubling does not round
    evaluate_at = cap
    previous_odd = None
    for round_index in range(SCAN_ROUNDS_MAX):
        decel, accel = interval_bounds(bounds, evaluate_at)
        e = climb(decel, ds2)
        c = e if accel is decel else climb(accel, ds2)  # symmetric bounds: one climb for both passes
        x = forward_pass(backward_pass(cap, e), c)
        np.maximum(x, 0.0, out=x)
        evaluate_at = x
        if round_index % 2 == 0:
            if previous_odd is not None and round_index + 1 >= SCAN_ROUNDS and \
                    float(np.max(x - previous_odd, initial=0.0)) <= SCAN_CONVERGED * float(x.max(initial=0.0)):
                break
            previous_odd = x
    return x
