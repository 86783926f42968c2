"""Slow-downs ahead: the highest feed from which every later cap can still be met at a_l.

Wang's feed adaptation is reactive: it limits the step by the curvature at the current
point only. On Table 1 that enters the ρ ≈ 6 mm turns at V0 = 200 mm/s, where
V0²/ρ ≈ 6.8 m/s²; no single cycle can then hold the resultant acceleration under
a_max = 2.5 m/s² (measured: 5.8 m/s² with the limits applied per cycle). The same reverse
idea that places the deceleration point for the stop gives the slow-downs: going backwards
from the stop, the feed may grow by a_l per unit of time, and never exceed the cap of the
adaptive limits at that point:
  V(s)² = min over s' <= s of (cap(s')² + 2 a_l (s - s')),  s measured back from the stop,
evaluated vectorised on a dense grid (numpy, once per run), as
V² = 2 a_l s + cumulative-min(cap² - 2 a_l s). The cap at each node is the smallest of the
node and its neighbours, so a curvature peak between nodes is not missed.
"""

from __future__ import annotations

from bisect import bisect_right
from math import ceil, sqrt

import numpy as np

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.planning.interpolators.feed import FeedLimits

GRID_SPACING_MM = 0.1  # node spacing along the path (about)
MIN_NODES_PER_BLOCK = 64


class SlowdownProfile:
    """V_ahead(j, u): the feed cap from the slow-downs still to come, per block of a run.

    Between two nodes the profile is read back from the later node along the a_l ramp,
    V² = min(V²_{i+1} + 2 a_l (s_{i+1} - s), cap²_i) with cap_i the smaller cap of the two
    nodes: exact on a ramp (V² is linear in s there), so a long straight line needs only
    its two end nodes.
    """

    def __init__(self, curves: list[NurbsCurve], feeds_mm_s: list[float], limits: FeedLimits, accel_mm_s2: float):
        grids, caps, lengths = [], [], []
        for curve, feed in zip(curves, feeds_mm_s):
            u, cap, seg = _block_caps(curve, feed, limits, accel_mm_s2)
            grids.append(u)
            caps.append(cap)
            lengths.append(seg)
        s = np.cumsum(np.concatenate(lengths))  # path length of every node along the run
        back = s[-1] - s[::-1]  # distance back from the stop, ascending
        cap = np.concatenate(caps)
        interval_cap2 = np.minimum(cap, np.r_[cap[1:], cap[-1]]) ** 2
        cap_back = cap[::-1].copy()
        cap_back[0] = 0.0  # the stop
        v2 = (2.0 * accel_mm_s2 * back + np.minimum.accumulate(cap_back * cap_back - 2.0 * accel_mm_s2 * back))[::-1]
        self.accel2 = 2.0 * accel_mm_s2
        self.u: list[list[float]] = []
        self.s: list[list[float]] = []
        self.v2: list[list[float]] = []
        self.cap2: list[list[float]] = []
        start = 0
        for grid in grids:
            stop = start + len(grid)
            self.u.append(grid.tolist())
            self.s.append(s[start:stop].tolist())
            self.v2.append(np.maximum(v2[start:stop], 0.0).tolist())
            self.cap2.append(interval_cap2[start:stop].tolist())
            start = stop

    def feed(self, j: int, u: float) -> float:
        """The profile at parameter u of block j (see the class doc)."""
        grid, v2 = self.u[j], self.v2[j]
        i = bisect_right(grid, u) - 1
        if i < 0:
            return sqrt(v2[0])
        if i >= len(grid) - 1:
            return sqrt(v2[-1])
        s = self.s[j]
        f = (u - grid[i]) / (grid[i + 1] - grid[i])
        ahead = (s[i + 1] - s[i]) * (1.0 - f)  # path length to the later node (linear in u)
        return sqrt(min(v2[i + 1] + self.accel2 * ahead, self.cap2[j][i]))


def subdivide(u: np.ndarray, seg: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Insert nodes into every interval longer than spacing_mm (seg[i] = length of interval i-1..i)."""
    parts = np.maximum(np.ceil(seg[1:] / spacing_mm).astype(int), 1)
    starts = np.repeat(u[:-1], parts)
    widths = np.repeat(np.diff(u) / parts, parts)
    offsets = np.arange(parts.sum()) - np.repeat(np.cumsum(parts) - parts, parts)
    return np.r_[starts + widths * offsets, u[-1]]


def _block_caps(curve: NurbsCurve, feed: float, limits: FeedLimits, accel_mm_s2: float):
    """Dense u grid of one block (node spacing <= about GRID_SPACING_MM along the path),
    the cap at each node, and the path length before each node."""
    points = curve.control_points
    if curve.degree == 1 and len(points) == 2:  # a straight line: no curvature, two nodes
        return (np.array([curve.u_min, curve.u_max]), np.full(2, feed),
                np.array([0.0, float(np.linalg.norm(points[1] - points[0]))]))
    polygon_mm = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    nodes = max(MIN_NODES_PER_BLOCK, ceil(polygon_mm / GRID_SPACING_MM) // 4 + 1)
    u = np.linspace(curve.u_min, curve.u_max, nodes)
    for _ in range(3):
        points, d1, d2 = curve.derivatives(u, 2)
        seg = np.r_[0.0, np.linalg.norm(np.diff(points, axis=0), axis=1)]
        if seg.max() <= 1.5 * GRID_SPACING_MM:
            break
        u = subdivide(u, seg, GRID_SPACING_MM)
    cap = np.full(len(u), feed)
    if limits.adaptive:
        speed2 = np.einsum("ij,ij->i", d1, d1)
        cross2 = speed2 * np.einsum("ij,ij->i", d2, d2) - np.einsum("ij,ij->i", d1, d2) ** 2
        with np.errstate(divide="ignore"):
            radius = np.where(cross2 > 0, speed2**1.5 / np.sqrt(np.maximum(cross2, 1e-300)), np.inf)
        cap = np.minimum(cap, limits.caps(radius, accel_mm_s2))
        cap = np.minimum(cap, np.minimum(np.r_[cap[1:], cap[-1]], np.r_[cap[0], cap[:-1]]))
    return u, cap, seg
