"""The discrete check of planned set-points: what the drives see, cycle by cycle.

Same definitions as planning.measure (the shared ruler), computed here on the planner's own
stretch of set-points so violations can be located and repaired:
- step n (from set-point n-1 to n): chord error = largest distance of the curve between the
  two set-points from their chord: inside a block, the bound kappa_max L^2 / 8 from the
  largest curvature on the step (step_chord_errors); across a block junction, sampled
  (three samples of every part between knots and the vertex of the parabola through them,
  every path grid point inside the step, and the junction itself); arc length on the true
  curve: the planned step
  plus the difference of the two set-points' arc-length residuals (sampling.py: s(u) by
  Gauss-Legendre from the nearest grid point, minus the planned s);
- at set-point n: |p_n+1 - 2 p_n + p_n-1| / T^2 (acceleration), per axis too, and
  |p_n+1 - 3 p_n + 3 p_n-1 - p_n-2| / T^3 (jerk), with the positions before the stretch
  (history, or the start held at rest) and after it (the end held at rest) included;
- per-axis velocity |p_n - p_n-1| / T;
- feed fluctuation on the arc: |arc(step) - planned ds| / planned ds;
- path deviation: the distance of every set-point on a corner blend from the two program
  pieces it replaces (blend.py; elsewhere the set-points lie on the program's curves), reported
  as ``max_path_deviation_mm``: the blends are sized within the tolerance, so no repair applies.
Every figure is compared with the machine's full limit; a set-point passes when
figure <= limit * (1 + TOLERANCE).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.planning.lookahead.path import BlockPiece, PathGrid, row_max, row_norms, to_3d
from nurbsmotion.planning.lookahead.sampling import Samples
from nurbsmotion.planning.lookahead.search import search_sorted
from nurbsmotion.planning.lookahead.speed_limits import window_min

TOLERANCE = 1e-9  # relative: rounding of the checks themselves
FLUCTUATION_LIMIT = 1e-6  # guaranteed |arc step - planned step| / planned step
MIN_STEP_FOR_FLUCTUATION_MM = 1e-6  # steps shorter than 1 nm (coming to rest) are exempt
# the arc-length arithmetic's resolution, relative to s: the residuals are sums of arc lengths
# of magnitude s (s_k + an integral - the planned s), each rounded to ~eps s
ARC_RESOLUTION = 64.0 * float(np.finfo(np.float64).eps)


@dataclass(frozen=True)
class MachineLimits:
    """The full machine limits the set-points are checked against."""

    period_s: float
    chord_error_mm: float
    accel_mm_s2: float
    jerk_mm_s3: float | None
    axis_velocity_mm_s: NDArray[np.float64] | None
    axis_accel_mm_s2: NDArray[np.float64] | None


@dataclass(eq=False)
class Check:
    """Per-set-point figures as ratios to their limits (1.0 = at the limit) and the maxima."""

    chord: NDArray[np.float64]  # step ending at n
    accel: NDArray[np.float64]
    jerk: NDArray[np.float64]
    axis_velocity: NDArray[np.float64]
    axis_accel: NDArray[np.float64]
    arc_fluctuation: NDArray[np.float64]  # absolute figure (not a ratio)
    chord_fluctuation: NDArray[np.float64]  # |chord - planned ds| / planned ds, for the report
    figures: dict[str, float]
    path_deviation: NDArray[np.float64] | None = None  # distance from the program / the corner's tolerance (blends)

    def violations(self) -> dict[str, NDArray[np.intp]]:
        """Set-point indices where a figure exceeds its limit (beyond the tolerance)."""
        out = {}
        for name in ("chord", "accel", "jerk", "axis_velocity", "axis_accel"):
            bad = np.flatnonzero(getattr(self, name) > 1.0 + TOLERANCE)
            if len(bad):
                out[name] = bad
        bad = np.flatnonzero(self.arc_fluctuation > FLUCTUATION_LIMIT)
        if len(bad):
            out["fluctuation"] = bad
        return out


def parabola_vertex(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Abscissa of the vertex of the parabola through three points per row (x, y: (m, 3))."""
    a, b = x[:, 1] - x[:, 0], x[:, 1] - x[:, 2]
    fa, fb = y[:, 1] - y[:, 2], y[:, 1] - y[:, 0]
    den = a * fa - b * fb
    num = a * a * fa - b * b * fb
    safe = np.where(np.abs(den) > 0, den, 1.0)
    return np.where(np.abs(den) > 0, x[:, 1] - 0.5 * num / safe, x[:, 1])


def distance_to_chord(points: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of points (m, k, 3) from segments a-b (m, 3), clamped to the segment."""
    ab = (b - a)[:, None, :]
    l2 = dot3(ab, ab)
    rel = points - a[:, None, :]
    t = np.clip(dot3(rel, ab) / np.where(l2 > 0, l2, 1.0), 0.0, 1.0)
    off = rel - t[..., None] * ab
    return np.sqrt(dot3(off, off))


def dot3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """a . b over the last axis of length 3 (x, y, z), column by column: numpy's sum over a
    last axis of 3 is ~5x slower."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


CHORD_FRACTIONS = np.array([0.25, 0.5, 0.75])


def part_chord_errors(curve, u0: NDArray[np.float64], u1: NDArray[np.float64], a: NDArray[np.float64],
                      b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest distance of the curve part [u0, u1] from chord a-b: three samples, then the
    vertex of the parabola through them (exact for the parabolic sag of a short smooth part)."""
    u = u0[:, None] + (u1 - u0)[:, None] * CHORD_FRACTIONS[None, :]
    dist = distance_to_chord(to_3d(curve.points(u.ravel())).reshape(len(u0), 3, 3), a, b)
    vertex = np.clip(parabola_vertex(u, dist), np.minimum(u0, u1), np.maximum(u0, u1))
    at_vertex = distance_to_chord(to_3d(curve.points(vertex))[:, None, :], a, b)[:, 0]
    return np.maximum(dist.max(axis=1), at_vertex)


def smooth_chord_errors(curve, u0: NDArray[np.float64], u1: NDArray[np.float64], a: NDArray[np.float64],
                        b: NDArray[np.float64]) -> NDArray[np.float64]:
    """part_chord_errors with every [u0, u1] split at the curve's knots (where x'' may jump)."""
    knots = curve.breakpoints
    first = np.searchsorted(knots, u0, side="right")
    last = np.searchsorted(knots, u1, side="left")
    dist = part_chord_errors(curve, u0, np.where(last > first, knots[np.minimum(first, len(knots) - 1)], u1), a, b)
    for i in np.flatnonzero(last > first):
        cuts = np.concatenate([knots[first[i]:last[i]], [u1[i]]])
        m = len(cuts) - 1
        extra = part_chord_errors(curve, cuts[:-1], cuts[1:], np.repeat(a[i:i + 1], m, 0), np.repeat(b[i:i + 1], m, 0))
        dist[i] = max(dist[i], extra.max())
    return dist


def grid_chord_errors(grid: PathGrid, s_prev: NDArray[np.float64], s: NDArray[np.float64], a: NDArray[np.float64],
                      b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest distance of the grid points inside each step (s_prev, s) from its chord a-b:
    catches sharp turns shorter than the step, which a few samples per step could miss."""
    out = np.zeros(len(s))
    step = search_sorted(s, grid.s, side="left")
    inside = (step < len(s)) & (grid.s > s_prev[np.minimum(step, len(s) - 1)])
    k = step[inside]
    d = distance_to_chord(grid.position[inside][:, None, :], a[k], b[k])[:, 0]
    np.maximum.at(out, k, d)
    return out


def junction_chord_error(grid: PathGrid, piece: NDArray[np.int32], u: NDArray[np.float64], p: NDArray[np.float64],
                         s: NDArray[np.float64], i: int) -> float:
    """Chord error of step i -> i+1 across block junctions (the path may turn a corner inside
    it): every piece touched, sampled, with its ends and the grid points inside the step."""
    a, b = p[i:i + 1], p[i + 1:i + 2]
    chord = 0.0
    for q in range(int(piece[i]), int(piece[i + 1]) + 1):
        part = grid.pieces[q]
        lo = u[i] if q == piece[i] else part.u_start
        hi = u[i + 1] if q == piece[i + 1] else part.u_end
        dist = smooth_chord_errors(part.curve, np.array([lo]), np.array([hi]), a, b)[0]
        ends = to_3d(part.curve.points(np.array([lo, hi])))[None]
        chord = max(chord, dist, float(distance_to_chord(ends, a, b).max()))
    inner = grid_chord_errors(grid, s[i:i + 1], s[i + 1:i + 2], a, b)
    return max(chord, float(inner[0]))


def step_chord_errors(grid: PathGrid, samples: Samples, s: NDArray[np.float64],
                      previous: Samples | None) -> NDArray[np.float64]:
    """Chord error of every step ending at a set-point of ``samples`` (step 0 joins the last
    set-point of ``previous`` at s = 0; without one it is 0).

    Inside one block: kappa_max L^2 / 8 with kappa_max the largest |x_ss| on the grid intervals
    the step touches (path.py) and L its arc length, at most the planned step x (1 +
    FLUCTUATION_LIMIT) (the fluctuation is checked too). The bound follows from the chord being
    the linear interpolant of x(s): |x(s) - chord(s)| <= max|x_ss| s (L - s) / 2. Across a
    junction: junction_chord_error."""
    piece, u, p = samples.piece, samples.u, samples.position_mm
    start = previous is not None and len(previous.u) > 0
    if start and previous is not None:
        piece = np.concatenate([previous.piece[-1:], piece])
        u = np.concatenate([previous.u[-1:], u])
        p = np.concatenate([previous.position_mm[-1:], p])
        s = np.concatenate([[0.0], s])
    if len(grid) < 2 or len(s) < 2:
        return np.zeros(len(samples.u))
    last = len(grid) - 2
    k_lo = np.clip(search_sorted(grid.s, s[:-1], side="right") - 1, 0, last)
    k_hi = np.clip(search_sorted(grid.s, s[1:], side="left") - 1, 0, last)
    kappa = -window_min(-grid.kappa_max, k_lo, np.maximum(k_hi, k_lo))
    arc = np.diff(s) * (1.0 + FLUCTUATION_LIMIT)
    chord = kappa * arc * arc / 8.0
    crossing = np.flatnonzero(piece[1:] != piece[:-1])
    polyline = crossing[polyline_steps(grid, piece[crossing], piece[crossing + 1])]
    if len(polyline):
        chord[polyline] = grid_chord_errors(grid, s[polyline], s[polyline + 1], p[polyline], p[polyline + 1])
    rest = np.setdiff1d(crossing, polyline, assume_unique=True)
    kink = junction_kinks(grid)
    turned = kink[piece[rest + 1]] - kink[piece[rest]]  # the kinks crossed (sum of their angles)
    smooth = turned <= SMOOTH_KINK_RAD
    # tangent joins (corner blends): the bound of a smooth step, plus what a kink of the
    # angles crossed could add (at most angle x L / 2)
    chord[rest[smooth]] += turned[smooth] * arc[rest[smooth]] / 2.0
    for i in rest[~smooth]:
        chord[i] = junction_chord_error(grid, piece, u, p, s, int(i))
    return chord if start else np.concatenate([[0.0], chord])


SMOOTH_KINK_RAD = 1e-7  # junctions turning less than this (summed over a step) are tangent joins


def junction_kinks(grid: PathGrid) -> NDArray[np.float64]:
    """(len(grid.pieces),) cumulative tangent turn at the junctions: entry q is the sum of the
    angles 2 asin(|t_after - t_before| / 2) at the junctions before piece q. A step across
    tangent joins only is bounded like a step inside a block: the chord is the linear
    interpolant of x(s), and |x - chord| <= max|x_ss| s (L - s) / 2 needs x(s) C1 with bounded
    x_ss, not one curve."""
    ends = np.flatnonzero(grid.junction)
    jump = row_norms(grid.tangent[ends + 1] - grid.tangent[ends])
    angle = 2.0 * np.arcsin(np.minimum(0.5 * jump, 1.0))
    return np.concatenate([[0.0], np.cumsum(angle)])


def polyline_steps(grid: PathGrid, first: NDArray[np.int32], last: NDArray[np.int32]) -> NDArray[np.bool_]:
    """Steps across junctions that touch straight pieces only (pieces first..last of each).

    Their chord error is exact from the grid points inside the step: the distance of a point
    moving along a line from a fixed segment is convex, so on a polyline it is largest at a
    vertex, and every vertex (junction) inside the step is a grid point."""
    curved = np.array([not (q.curve.degree == 1 and len(q.curve.control_points) == 2) for q in grid.pieces])
    curved_before = np.concatenate([[0], np.cumsum(curved)])
    return curved_before[last + 1] - curved_before[first] == 0


def path_deviations(grid: PathGrid, samples: Samples) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(distance of every set-point from the programmed path, that / its corner's path
    tolerance): 0 off the corner blends and smoothed pieces (the set-points lie on the
    program's own curves); on a blend, the distance to the two pieces it replaces (exact for
    lines and arcs); on a smoothed piece and a blend next to one, to the program's lines they
    stand for (``BlockPiece.near``)."""
    n = len(samples.u)
    distance, ratio = np.zeros(n), np.zeros(n)
    sets = {id(p.corners): p.corners for p in grid.pieces if p.corners is not None}
    for corners in sets.values():
        corner = np.array([p.corner if p.corners is corners else -1 for p in grid.pieces])[samples.piece]
        rows = np.flatnonzero(corner >= 0)
        c = corner[rows]
        q = samples.position_mm[rows][:, None, :]
        d = np.minimum(corners.incoming.take(c).distance(q), corners.outgoing.take(c).distance(q))[:, 0]
        distance[rows] = d
        ratio[rows] = d / corners.tolerance_mm[c]
    for k, piece in enumerate(grid.pieces):
        if piece.near is None:
            continue
        rows = np.flatnonzero(samples.piece == k)
        if len(rows):
            distance[rows] = near_distances(piece, samples.u[rows], samples.position_mm[rows])
            ratio[rows] = distance[rows] / piece.near.tolerance_mm
    return distance, ratio


NEAR_SEGMENTS = 4  # a set-point on a smoothed piece is measured against its block's segment and this many either side


def near_distances(piece: BlockPiece, u: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of set-points on ``piece`` from the program's lines it stands for: on a
    smoothed piece the segments of the block reached (Covered) and NEAR_SEGMENTS either side,
    a subset, so never less than the true distance; on a blend all of them (a few)."""
    assert piece.near is not None
    near = piece.near.pieces
    if piece.covered is None:
        q = np.broadcast_to(points[None], (len(near.length_mm), len(points), 3))
        return near.distance(q).min(axis=0)
    at = np.searchsorted(piece.covered.u_end, u, side="left")
    offsets = np.arange(-NEAR_SEGMENTS, NEAR_SEGMENTS + 1)
    index = np.clip(at[:, None] + offsets[None, :], 0, len(near.length_mm) - 1)
    q = np.repeat(points, len(offsets), axis=0)[:, None, :]
    return near.take(index.ravel()).distance(q)[:, 0].reshape(len(points), len(offsets)).min(axis=1)


def rows_max(values: NDArray[np.float64], first_row: int, n: int) -> NDArray[np.float64]:
    """Per-row maximum of ``values`` placed on consecutive rows first_row, first_row + 1, ...;
    rows before 0 count for row 0 and rows past n - 1 for row n - 1."""
    out = np.zeros(n)
    if n == 0 or len(values) == 0:
        return out
    lo, hi = max(-first_row, 0), min(n - first_row, len(values))  # values landing inside 0..n-1
    if hi > lo:
        out[first_row + lo: first_row + hi] = values[lo:hi]
    if lo > 0:
        out[0] = max(out[0], float(values[:lo].max()))
    if hi < len(values):
        out[n - 1] = max(out[n - 1], float(values[max(hi, 0):].max()))
    return out


def arc_excess_mm(residual_step_mm: NDArray[np.float64], s_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """|arc(step) - planned step| beyond what the arithmetic resolves at s (ARC_RESOLUTION s):
    a step of 3 nm at the end of a 1 m curve cannot be resolved to 1e-6 of itself (3e-15 mm,
    below one rounding of s), so its rounding-level residuals (~4e-12 mm) are no fluctuation."""
    return np.maximum(np.abs(residual_step_mm) - ARC_RESOLUTION * np.abs(s_mm), 0.0)


def check(grid: PathGrid, samples: Samples, s: NDArray[np.float64], planned_ds: NDArray[np.float64], limits: MachineLimits,
          before: NDArray[np.float64], after: NDArray[np.float64], previous: Samples | None) -> Check:
    """All figures of a stretch of n set-points. ``before``: the 3 positions preceding it (the
    start held at rest, or the previous stretch's last three); ``after``: the positions
    following it (the end held at rest, or none when the plan goes on). Differences that
    involve a previous set-point are attributed to row 0."""
    period = limits.period_s
    p = samples.position_mm
    n, nb = len(p), len(before)
    full = np.concatenate([before, p, after])
    step = np.diff(full, axis=0)[nb - 1: nb - 1 + n]  # p_n - p_n-1
    second = full[2:] - 2.0 * full[1:-1] + full[:-2]  # centred on full[j + 1]
    third = full[3:] - 3.0 * full[2:-1] + 3.0 * full[1:-2] - full[:-3]  # row of full[j + 2]
    first2, first3 = max(nb - 2, 0), max(nb - 3, 0)  # differences that involve a set-point of this stretch
    accel_vec = second[first2:] / period**2
    accel = rows_max(row_norms(accel_vec), first2 + 1 - nb, n)
    jerk = rows_max(row_norms(third[first3:]) / period**3, first3 + 2 - nb, n)
    chord = step_chord_errors(grid, samples, s, previous)
    planned = np.asarray(planned_ds, dtype=float)
    moving = planned > MIN_STEP_FOR_FLUCTUATION_MM
    safe = np.where(moving, planned, 1.0)
    residual = samples.arc_residual_mm
    if residual is None:
        raise ValueError("check() needs samples with arc residuals (sample_path sets them)")
    residual_before = np.concatenate([[0.0 if previous is None or previous.arc_residual_mm is None
                                       else previous.arc_residual_mm[-1]], residual[:-1]])
    residual_step = residual - residual_before
    arc_fl = np.where(moving, np.abs(residual_step) / safe, 0.0)
    over = np.flatnonzero(arc_fl > FLUCTUATION_LIMIT)  # rare: measured again beyond the rounding of s
    arc_fl[over] = arc_excess_mm(residual_step[over], s[over]) / safe[over]
    chord_fl = np.where(moving, np.abs(row_norms(step) - planned) / safe, 0.0)
    zeros = np.zeros(n)
    axis_v = (row_max(np.abs(step) / period / limits.axis_velocity_mm_s)
              if limits.axis_velocity_mm_s is not None else zeros)
    axis_a = (rows_max(row_max(np.abs(accel_vec) / limits.axis_accel_mm_s2), first2 + 1 - nb, n)
              if limits.axis_accel_mm_s2 is not None else zeros)
    figures = {
        "max_chord_error_mm": float(chord.max(initial=0.0)),
        "max_accel_mm_s2": float(accel.max(initial=0.0)),
        "max_jerk_mm_s3": float(jerk.max(initial=0.0)),
        "max_arc_fluctuation": float(arc_fl.max(initial=0.0)),
        "max_chord_fluctuation": float(chord_fl.max(initial=0.0)),
    }
    deviation, deviation_ratio = path_deviations(grid, samples)
    figures["max_path_deviation_mm"] = float(deviation.max(initial=0.0))
    for i, name in enumerate("xyz"):  # column by column: numpy's reduction over axis 0 of (n, 3) is ~15x slower
        figures[f"max_{name}_velocity_mm_s"] = float(np.abs(step[:, i]).max(initial=0.0) / period)
        figures[f"max_{name}_accel_mm_s2"] = float(np.abs(accel_vec[:, i]).max(initial=0.0))
    return Check(
        chord=chord / limits.chord_error_mm,
        accel=accel / limits.accel_mm_s2,
        jerk=jerk / limits.jerk_mm_s3 if limits.jerk_mm_s3 is not None else zeros,
        axis_velocity=axis_v,
        axis_accel=axis_a,
        arc_fluctuation=arc_fl,
        chord_fluctuation=chord_fl,
        figures=figures,
        path_deviation=deviation_ratio,
    )
