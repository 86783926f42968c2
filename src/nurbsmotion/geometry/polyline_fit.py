"""Runs of short G01 moves replaced by one curvature-continuous cubic B-spline within a tolerance
("nano smoothing", Fanuc; COMPCAD, Siemens; LinuxCNC's G64 Q naive-CAM tolerance).

Which runs (``smoothable_runs``): consecutive segments each shorter than ``max_segment_mm``
whose direction turns by less than ``corner_deg`` at every interior vertex, at least
``min_segments`` of them, without a feed change or a caller's break inside. A sharper vertex
ends the run and stays a corner (the look-ahead blends it); longer segments stay lines.
Defaults, from the corpus in tests/data/gcode (the 67,324 G01 segments of every program the
reader accepts, measured 2026-11-28, docs/smoothing.md): 90 % of all segments are under 4 mm and the
surface/contour programs (camotics_bear, linuxcnc_3D_Chips, LHchips4, grbl_HSM_test) have
96-100 % under 5 mm, so ``max_segment_mm = 5``; the turning angles between consecutive
segments are dense below 20 deg (sampled curves) and thin out from 25 deg until the real
corners at 60-135 deg, so ``corner_deg = 30`` (Siemens recommends 36 deg for COMPCAD's
SD42470 $SC_CRIT_SPLINE_ANGLE, "values between 10 and 40 degrees are useful"). Given the
tolerance, a vertex also ends runs where the polyline is a polygon at that tolerance: a smooth
curve turning by theta over chords of length l bulges l theta / 8 from them (``coarse_vertices``).
Runs longer than DEFAULT_MAX_RUN_SEGMENTS are cut at their straightest vertex (the dense solve
stays small; both pieces have curvature 0 there, so the path stays G2).

The fit (``fit_run``): chord-length parametrised least squares with adaptive knot insertion
(Piegl & Tiller, The NURBS Book, ch. 9.4.1 and A9.7's idea): u is the cumulative chord length
in mm, so |x'| ~ 1. A cubic is C2 (curvature continuous), the lowest degree that is. The end
conditions are fixed, not fitted: P0 = Q0, P1 = Q0 + t0 k1/3, P2 = Q0 + t0 (k1 + k2)/3 (k1, k2
the first two interior knots; the mirror image at the end) give x(0) = Q0, x'(0) = t0 (unit
speed along the first segment) and x''(0) = 0 (P&T eq. 3.9: x''(0) is proportional to
(P2 - P1)/k2 - (P1 - P0)/k1 = 0), so the curve joins the neighbouring lines G2 (curvature 0 on
both sides). With the ends fixed the unknowns separate by coordinate: one symmetric solve of
the normal equations for all three. A small penalty on the control points' second differences
(lambda |P_(i-1) - 2 P_i + P_(i+1)|^2, a P-spline, Eilers & Marx 1996) keeps spans without
data determined and the control polygon free of wiggles. The data are the vertices, the
segment midpoints (the curve is held between the vertices and the chords: both must be within
the tolerance) and DATA_PER_SPAN polyline points inside every knot span (a span that knot
insertion made short is still held by data). The first knots are spread evenly over arc
length plus turning angle and graded toward the ends; after each solve every span where the
deviation exceeds TARGET_FRACTION of the tolerance is halved, and the fit is solved again
(each round first checks the data's residuals normal to the polyline, and measures the
deviation, ``deviations``, only when those pass). Least squares rather than interpolation:
the curve averages the CAM's rounding noise instead of following it, and a smooth run needs
far fewer control points than it has vertices. Local knot insertion rather than recursive
splitting of the run: one spline, C2 at every knot, no extra curvature-0 joins.

Deviation (``max_deviation``), both ways and conservative (every figure is the distance to a
point that exists, so it can only over-estimate): each vertex to the curve (the nearest of
dense curve samples near the vertex's arc-length position, refined by Newton's foot-point
iteration) and each curve sample (``samples_per_segment`` per segment) to the polyline
segments near it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.geometry.nurbs import NurbsCurve

DEFAULT_MAX_SEGMENT_MM = 5.0
DEFAULT_CORNER_DEG = 30.0
DEFAULT_MIN_SEGMENTS = 3
DEFAULT_MAX_RUN_SEGMENTS = 400  # longer runs are cut at their straightest vertex: bounds the dense solve
DEGREE = 3
SAME_POINT_MM = 1e-9  # consecutive vertices closer than this are one vertex
SMOOTHING_PENALTY = 1e-4  # lambda of the second-difference penalty (dimensionless: both terms are mm^2)
TARGET_FRACTION = 0.9  # spans are split until every deviation is below this fraction of the tolerance
SPAN_TURN_RAD = math.radians(30.0)  # first knots: about one span per 30 deg of turning
MAX_ROUNDS = 30
SAMPLES_PER_SEGMENT = 4  # curve samples per polyline segment (and one more evenly in u)
NEIGHBOUR_SEGMENTS = 1  # a curve sample is compared with the segments this far from its own
SEARCH_SEGMENTS = 3  # a vertex's foot point is searched among curve samples this many segments around it
NEWTON_DONE = 1e-7  # stop Newton when every step is below this (in u, mm: the distance then errs by ~ step^2)
NEWTON_STEPS = 4
DATA_PER_SPAN = 4  # polyline points fitted inside every knot span besides vertices and midpoints
END_VERTICES = 5  # the end curvature is the largest Menger curvature of this many vertices


class FitError(ValueError):
    """A run that cannot be fitted (bad input, or no spline within the tolerance): one line."""


@dataclass(frozen=True)
class RunSpan:
    """Vertices ``first`` .. ``last`` (inclusive) of a polyline: ``last - first`` segments."""

    first: int
    last: int

    @property
    def segments(self) -> int:
        return self.last - self.first

    def vertices(self, points: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(points, dtype=np.float64)[self.first: self.last + 1]


@dataclass(frozen=True)
class Deviation:
    """The two one-sided distances between a curve and a polyline, in mm."""

    vertex_to_curve_mm: float
    curve_to_polyline_mm: float

    @property
    def max_mm(self) -> float:
        return max(self.vertex_to_curve_mm, self.curve_to_polyline_mm)


@dataclass(frozen=True)
class CurvatureReport:
    """Largest curvature of the fitted curve against the polyline's discrete (Menger) curvature."""

    curve_per_mm: float
    polyline_per_mm: float


# ---- input -------------------------------------------------------------------------------------

def _as_points(points: ArrayLike, field: str = "points") -> NDArray[np.float64]:
    """An (N, dim) float array of finite numbers, or FitError naming the first bad vertex."""
    try:
        array = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise FitError(f"{field}: must be numbers ({err})") from None
    if array.ndim != 2 or array.shape[1] < 1:
        raise FitError(f"{field}: must be a list of points of equal dimension, got shape {array.shape}")
    bad = np.flatnonzero(~np.isfinite(array).all(axis=1))
    if len(bad):
        raise FitError(f"{field}: vertex {int(bad[0])} is not a finite point")
    return array


def distinct_vertices(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """The polyline without repeated consecutive vertices (first and last vertex kept exactly)."""
    if len(points) < 2:
        return points
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    keep = np.concatenate([[True], step > SAME_POINT_MM])
    out = points[keep]
    if not keep[-1]:
        out = out.copy()
        out[-1] = points[-1]
    return out


# ---- which runs ------------------------------------------------------------------------------

def _turning_rad(segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """Turning angle at each interior vertex between the nearest non-zero segments before and
    after it (zero-length segments do not turn); len(segments) - 1 values."""
    lengths = np.linalg.norm(segments, axis=1)
    nonzero = lengths > SAME_POINT_MM
    if len(segments) < 2:
        return np.zeros(0)
    index = np.arange(len(segments))
    before = np.maximum.accumulate(np.where(nonzero, index, -1))[:-1]
    after_rev = np.minimum.accumulate(np.where(nonzero, index, len(segments))[::-1])[::-1][1:]
    valid = (before >= 0) & (after_rev < len(segments))
    units = segments / np.where(nonzero, lengths, 1.0)[:, None]
    a = units[np.clip(before, 0, None)]
    b = units[np.clip(after_rev, None, len(segments) - 1)]
    cos = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    return np.where(valid, np.arccos(cos), 0.0)


def smoothable_runs(points: ArrayLike, feeds_mm_s: ArrayLike | None = None, *,
                    max_segment_mm: float = DEFAULT_MAX_SEGMENT_MM, corner_deg: float = DEFAULT_CORNER_DEG,
                    min_segments: int = DEFAULT_MIN_SEGMENTS, max_run_segments: int = DEFAULT_MAX_RUN_SEGMENTS,
                    breaks: ArrayLike | None = None, tolerance_mm: float | None = None) -> list[RunSpan]:
    """Maximal runs of segments shorter than ``max_segment_mm`` joined at vertices that turn by
    less than ``corner_deg``, where the feed (one per segment) does not change and ``breaks``
    (one bool per vertex: an event, exact stop, ...) is False; at least ``min_segments`` each.
    With ``tolerance_mm``, a vertex also ends runs when a smooth curve through it would leave
    its chords by more than that (``coarse_vertices``): there the polyline is a polygon at this
    tolerance, and a fit would only trace its corners with many control points.
    Runs longer than ``max_run_segments`` are cut at their straightest vertex in the second half
    of each window (both pieces end with curvature 0 there, so the path stays G2)."""
    pts = _as_points(points)
    if not max_segment_mm > 0 or not 0 < corner_deg <= 180 or min_segments < 2 or max_run_segments < min_segments:
        raise FitError(f"smoothable_runs: need max_segment_mm > 0, 0 < corner_deg <= 180, min_segments >= 2 and "
                       f"max_run_segments >= min_segments; got {max_segment_mm}, {corner_deg}, {min_segments}, "
                       f"{max_run_segments}")
    n_seg = len(pts) - 1
    if n_seg < 1:
        return []
    segments = np.diff(pts, axis=0)
    short = np.linalg.norm(segments, axis=1) < max_segment_mm
    turning = _turning_rad(segments)
    joins = short[:-1] & short[1:] & (turning < math.radians(corner_deg))  # at interior vertices 1..n-1
    if feeds_mm_s is not None:
        feeds = np.asarray(feeds_mm_s, dtype=np.float64)
        if feeds.shape != (n_seg,):
            raise FitError(f"feeds_mm_s: need one feed per segment ({n_seg}), got shape {feeds.shape}")
        joins &= feeds[:-1] == feeds[1:]
    if breaks is not None:
        stop = np.asarray(breaks, dtype=bool)
        if stop.shape != (len(pts),):
            raise FitError(f"breaks: need one flag per vertex ({len(pts)}), got shape {stop.shape}")
        joins &= ~stop[1:-1]
    if tolerance_mm is not None:
        joins &= ~coarse_vertices(segments, turning, tolerance_mm)
    runs = []
    for first_seg, last_seg in _chains(short, joins):
        runs += _cut_long_run(first_seg, last_seg + 1, turning, max_run_segments)
    return [r for r in runs if r.segments >= min_segments]


def coarse_vertices(segments: NDArray[np.float64], turning_rad: NDArray[np.float64], tolerance_mm: float
                    ) -> NDArray[np.bool_]:
    """Interior vertices where the polyline is no sampled smooth curve at this tolerance: a
    curve turning by theta over chords of mean length l bulges l theta / 8 from them (the chord
    sag l^2 / (8 R) with theta = l / R), more than ``tolerance_mm``."""
    lengths = np.linalg.norm(segments, axis=1)
    mean_mm = (lengths[:-1] + lengths[1:]) / 2.0
    return mean_mm * turning_rad / 8.0 > tolerance_mm


def _chains(short: NDArray[np.bool_], joins: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(first, last) segment index of each maximal chain of short segments linked by joins."""
    starts = np.flatnonzero(short & np.concatenate([[True], ~joins]))
    ends = np.flatnonzero(short & np.concatenate([~joins, [True]]))
    return list(zip(starts.tolist(), ends.tolist()))


def _cut_long_run(first: int, last: int, turning: NDArray[np.float64], max_segments: int) -> list[RunSpan]:
    """Vertex spans of at most ``max_segments`` segments covering first..last (vertex indices)."""
    spans = []
    while last - first > max_segments:
        lo, hi = first + max_segments // 2, first + max_segments  # candidate cut vertices
        cut = lo + int(np.argmin(turning[lo - 1: hi]))  # turning[v - 1] is at vertex v
        spans.append(RunSpan(first, cut))
        first = cut
    spans.append(RunSpan(first, last))
    return spans


# ---- B-spline basics ------------------------------------------------------------------------

def _clamped_knots(interior: NDArray[np.float64], length: float) -> NDArray[np.float64]:
    return np.concatenate([np.zeros(DEGREE + 1), interior, np.full(DEGREE + 1, length)])


def cubic_basis(knots: NDArray[np.float64], u: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """(span, B): the knot span k of each u and the 4 non-zero cubic basis functions
    N_(k-3..k),3(u) (Cox-de Boor, P&T A2.2, vectorised over u)."""
    span = np.clip(np.searchsorted(knots, u, side="right") - 1, DEGREE, len(knots) - DEGREE - 2)
    basis = np.zeros((len(u), DEGREE + 1))
    basis[:, 0] = 1.0
    left = [np.zeros(0)] + [u - knots[span + 1 - j] for j in range(1, DEGREE + 1)]
    right = [np.zeros(0)] + [knots[span + j] - u for j in range(1, DEGREE + 1)]
    for j in range(1, DEGREE + 1):
        saved = np.zeros(len(u))
        for r in range(j):
            temp = basis[:, r] / (right[r + 1] + left[j - r])
            basis[:, r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        basis[:, j] = saved
    return span, basis


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v)


def end_control_points(q: NDArray[np.float64], interior: NDArray[np.float64], length: float
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(P0, P1, P2) and (P_(n-2), P_(n-1), P_n): the end at the vertex, unit speed along the end
    segment, zero second derivative (module docstring)."""
    t0, t1 = _unit(q[1] - q[0]), _unit(q[-1] - q[-2])
    k1, k2 = interior[0], interior[1]
    e1, e2 = length - interior[-1], length - interior[-2]
    start = np.array([q[0], q[0] + t0 * k1 / 3.0, q[0] + t0 * (k1 + k2) / 3.0])
    end = np.array([q[-1] - t1 * (e1 + e2) / 3.0, q[-1] - t1 * e1 / 3.0, q[-1]])
    return start, end


def _curve(control_points: NDArray[np.float64], knots: NDArray[np.float64]) -> NurbsCurve:
    return NurbsCurve.create(DEGREE, control_points, None, knots)


# ---- least squares ------------------------------------------------------------------------

def _fit_data(q: NDArray[np.float64], s: NDArray[np.float64], interior: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, target points): the polyline X(u) at chord length u for the vertices, the segment
    midpoints and DATA_PER_SPAN points inside every knot span, so that each span, however short
    knot insertion makes it, is held by data (an approximation of min integral |x(u) - X(u)|^2)."""
    breaks = np.concatenate([[0.0], interior, [s[-1]]])
    inside = (breaks[:-1, None] + np.diff(breaks)[:, None] * (np.arange(1, DATA_PER_SPAN + 1) / (DATA_PER_SPAN + 1))).ravel()
    u = np.concatenate([s, (s[:-1] + s[1:]) / 2.0, inside])
    target = np.column_stack([np.interp(u, s, q[:, k]) for k in range(q.shape[1])])
    return u, target


@dataclass(frozen=True)
class LeastSquaresFit:
    """``control``: the control points; ``u``: the data parameters; ``off_path_mm``: each
    datum's residual |x(u) - X(u)| without its part along the polyline's segment at u, a cheap
    estimate of how far the curve is from the polyline there (no foot points)."""

    control: NDArray[np.float64]
    u: NDArray[np.float64]
    off_path_mm: NDArray[np.float64]


def least_squares_fit(q: NDArray[np.float64], s: NDArray[np.float64], interior: NDArray[np.float64]) -> LeastSquaresFit:
    """The penalised least-squares cubic on the clamped knots with these interior knots:
    min sum |x(u_r) - X_r|^2 + lambda sum |P_(i-1) - 2 P_i + P_(i+1)|^2 over the free control
    points P_3 .. P_(n-3), the three at each end fixed (``end_control_points``)."""
    length = float(s[-1])
    knots = _clamped_knots(interior, length)
    n_points = len(interior) + DEGREE + 1
    start, end = end_control_points(q, interior, length)
    control = np.zeros((n_points, q.shape[1]))
    control[:3], control[-3:] = start, end
    u, target = _fit_data(q, s, interior)
    span, basis = cubic_basis(knots, u)
    cols = span[:, None] - DEGREE + np.arange(DEGREE + 1)
    if n_points > 6:
        normal = np.bincount((cols[:, :, None] * n_points + cols[:, None, :]).ravel(),
                             (basis[:, :, None] * basis[:, None, :]).ravel(), n_points * n_points)
        normal = normal.reshape(n_points, n_points)
        rhs = np.zeros((n_points, q.shape[1]))
        np.add.at(rhs, cols.ravel(), (basis[:, :, None] * target[:, None, :]).reshape(-1, q.shape[1]))
        second = np.diff(np.eye(n_points), 2, axis=0)
        normal += SMOOTHING_PENALTY * (second.T @ second)
        free = slice(3, n_points - 3)
        fixed = np.r_[0:3, n_points - 3:n_points]
        rhs_free = rhs[free] - normal[free][:, fixed] @ control[fixed]
        control[free] = np.linalg.solve(normal[free, free], rhs_free)
    residual = np.einsum("rk,rkd->rd", basis, control[cols]) - target
    directions = np.diff(q, axis=0)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    along = directions[np.clip(np.searchsorted(s, u, side="right") - 1, 0, len(q) - 2)]
    off = residual - np.einsum("rd,rd->r", residual, along)[:, None] * along
    return LeastSquaresFit(control, u, np.sqrt(np.einsum("rd,rd->r", off, off)))


def _menger_curvature(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """2 sin(theta) / |Q_(i+1) - Q_(i-1)| at each interior vertex (the circle through three vertices)."""
    theta = _turning_rad(np.diff(q, axis=0))
    chord = np.linalg.norm(q[2:] - q[:-2], axis=1)
    return 2.0 * np.sin(theta) / np.where(chord > 0, chord, np.inf)


def _graded_end_knots(kappa: float, first_regular: float, tolerance_mm: float) -> list[float]:
    """Knots from one end toward the first regular knot at l, 2 l, 4 l, ...: the curvature rises
    from 0 at the end to kappa over the first span, which leaves the circle of curvature kappa by
    about kappa l^2 / 6, so l = sqrt(6 tol / kappa) / 2 keeps well inside the tolerance."""
    if kappa <= 0:
        return []
    step = math.sqrt(6.0 * tolerance_mm / kappa) / 2.0
    knots = []
    while step < first_regular / 2.0:
        knots.append(step)
        step *= 2.0
    return knots


def _first_knots(q: NDArray[np.float64], s: NDArray[np.float64], tolerance_mm: float) -> NDArray[np.float64]:
    """Interior knots at equal steps of g(s) = (s / L + phi(s) / Phi) / 2, phi the turning up to s:
    about one span per SPAN_TURN_RAD, denser where the polyline turns; at least 3; then graded
    toward each end (``_graded_end_knots``), where the curvature must come down to 0."""
    turning = np.concatenate([[0.0], np.cumsum(_turning_rad(np.diff(q, axis=0))), [0.0]])
    turning[-1] = turning[-2]
    total = turning[-1]
    spans = max(4, math.ceil(total / SPAN_TURN_RAD) + 1)
    g = s / s[-1] if total <= 1e-12 else 0.5 * (s / s[-1] + turning / total)
    regular = np.interp(np.arange(1, spans) / spans, g, s)
    kappa = _menger_curvature(q)
    length = float(s[-1])
    start = _graded_end_knots(float(kappa[:END_VERTICES].max(initial=0.0)), regular[0], tolerance_mm)
    end = _graded_end_knots(float(kappa[-END_VERTICES:].max(initial=0.0)), length - regular[-1], tolerance_mm)
    return np.unique(np.concatenate([start, regular, length - np.array(end, dtype=np.float64)]))


# ---- deviation ----------------------------------------------------------------------------

@dataclass(frozen=True)
class _Segments:
    """The polyline's segments a -> a + ab with |ab|^2, for distances to many points."""

    a: NDArray[np.float64]
    ab: NDArray[np.float64]
    len2: NDArray[np.float64]

    @classmethod
    def of(cls, q: NDArray[np.float64]) -> "_Segments":
        ab = np.diff(q, axis=0)
        len2 = np.einsum("ij,ij->i", ab, ab)
        return cls(q[:-1], ab, np.where(len2 > 0, len2, 1.0))

    def distances(self, x: NDArray[np.float64], index: NDArray[np.intp]) -> NDArray[np.float64]:
        """Distance from each point x[i] to each segment index[i, k]: shape index.shape."""
        rel = x[:, None, :] - self.a[index]
        ab = self.ab[index]
        t = np.clip(np.einsum("ijk,ijk->ij", rel, ab) / self.len2[index], 0.0, 1.0)
        off = rel - t[:, :, None] * ab
        return np.sqrt(np.einsum("ijk,ijk->ij", off, off))


def _foot_points(curve: NurbsCurve, q: NDArray[np.float64], u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Newton's foot-point iteration (P&T eq. 6.3) from u, clamped to the curve's range:
    u <- u - x'.(x - q) / (x''.(x - q) + |x'|^2). Returns (u, |x(u) - q|), the best seen."""
    best_u = u
    best = np.full(len(q), np.inf)
    for _ in range(NEWTON_STEPS):
        x, d1, d2 = curve.derivatives(u, 2)
        r = x - q
        dist = np.sqrt(np.einsum("ij,ij->i", r, r))
        better = dist < best
        best_u, best = np.where(better, u, best_u), np.where(better, dist, best)
        denom = np.einsum("ij,ij->i", d2, r) + np.einsum("ij,ij->i", d1, d1)
        step = np.einsum("ij,ij->i", d1, r) / np.where(denom > 0, denom, np.inf)
        u = np.clip(u - step, curve.u_min, curve.u_max)
        if np.abs(step).max() < NEWTON_DONE:
            break
    r = curve.derivatives(u, 0)[0] - q
    dist = np.sqrt(np.einsum("ij,ij->i", r, r))
    better = dist < best
    return np.where(better, u, best_u), np.where(better, dist, best)


def _vertex_parameters(curve: NurbsCurve, q: NDArray[np.float64], samples: int) -> NDArray[np.float64]:
    """A start value for each vertex's foot point: the nearest of ``samples`` curve samples per
    segment among those within SEARCH_SEGMENTS segments of the vertex's arc-length fraction."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    n_samples = samples * (len(q) - 1) + 1
    grid = np.linspace(curve.u_min, curve.u_max, n_samples)
    x = curve.derivatives(grid, 0)[0]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
    centre = np.searchsorted(arc / arc[-1], s / s[-1]) if arc[-1] > 0 else np.zeros(len(q), np.intp)
    offsets = np.arange(-SEARCH_SEGMENTS * samples, SEARCH_SEGMENTS * samples + 1)
    window = np.clip(centre[:, None] + offsets, 0, n_samples - 1)
    dist = np.linalg.norm(x[window] - q[:, None, :], axis=2)
    return grid[window[np.arange(len(q)), np.argmin(dist, axis=1)]]


def deviations(curve: NurbsCurve, points: ArrayLike, samples_per_segment: int = SAMPLES_PER_SEGMENT,
               u_guess: NDArray[np.float64] | None = None
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(vertex u, vertex distance, sample u, sample distance): each vertex's foot point on the
    curve and its distance, and curve samples (``samples_per_segment`` between consecutive foot
    points, and one per segment evenly in u) with their distance to the polyline segments within
    NEIGHBOUR_SEGMENTS of the sample's own. ``u_guess``: start values of the foot points (one
    per distinct vertex), found by a windowed search over curve samples when None."""
    q = distinct_vertices(_as_points(points))
    if len(q) < 2:
        dist = np.linalg.norm(curve.derivatives(np.array([curve.u_min]), 0)[0] - q, axis=1)
        return np.full(len(q), curve.u_min), dist, np.zeros(0), np.zeros(0)
    start = _vertex_parameters(curve, q, samples_per_segment) if u_guess is None else u_guess
    u_vertex, d_vertex = _foot_points(curve, q, start)
    order = np.maximum.accumulate(u_vertex)
    fractions = np.arange(samples_per_segment) / samples_per_segment
    along = (order[:-1, None] + np.diff(order)[:, None] * fractions).ravel()
    uniform = np.linspace(curve.u_min, curve.u_max, len(q))
    u_sample = np.concatenate([along, uniform])
    x = curve.derivatives(u_sample, 0)[0]
    own = np.searchsorted(order, u_sample, side="right") - 1
    near = np.clip(own[:, None] + np.arange(-NEIGHBOUR_SEGMENTS, NEIGHBOUR_SEGMENTS + 1), 0, len(q) - 2)
    d_sample = _Segments.of(q).distances(x, near).min(axis=1)
    return u_vertex, d_vertex, u_sample, d_sample


def max_deviation(curve: NurbsCurve, points: ArrayLike, samples_per_segment: int = SAMPLES_PER_SEGMENT) -> Deviation:
    """Largest vertex-to-curve and curve-to-polyline distance (``deviations``), in mm."""
    _, d_vertex, _, d_sample = deviations(curve, points, samples_per_segment)
    return Deviation(float(d_vertex.max(initial=0.0)), float(d_sample.max(initial=0.0)))


# ---- the fit -------------------------------------------------------------------------------

def _straight_curve(q: NDArray[np.float64]) -> NurbsCurve:
    """The cubic Bezier of the chord first..last vertex at unit speed (curvature 0 throughout)."""
    length = float(np.linalg.norm(q[-1] - q[0]))
    control = q[0] + np.outer(np.arange(4) / 3.0, q[-1] - q[0])
    control[-1] = q[-1]
    return _curve(control, _clamped_knots(np.zeros(0), length))


def _spans_to_split(knots: NDArray[np.float64], bad_u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Midpoints of the distinct knot spans that hold a bad parameter."""
    breaks = np.unique(knots)
    spans = np.unique(np.clip(np.searchsorted(breaks, bad_u, side="right") - 1, 0, len(breaks) - 2))
    return (breaks[spans] + breaks[spans + 1]) / 2.0


def fit_run(points: ArrayLike, tolerance_mm: float, max_control_points: int | None = None) -> NurbsCurve:
    """A cubic B-spline from the first to the last vertex, G2 to the end segments (curvature 0
    at both ends), within ``tolerance_mm`` of the polyline both ways (module docstring).

    FitError when the input is bad or no fit within ``max_control_points`` and MAX_ROUNDS of
    knot insertion keeps the tolerance: keep the lines then. The default, the run's vertices
    + 8, refuses fits that simplify nothing (a run of a few vertices may take up to 8 more)."""
    if isinstance(tolerance_mm, bool) or not isinstance(tolerance_mm, (int, float)) \
            or not (math.isfinite(tolerance_mm) and tolerance_mm > 0):
        raise FitError(f"tolerance_mm: must be a number > 0, got {tolerance_mm!r}")
    q = distinct_vertices(_as_points(points))
    if len(q) < 2:
        raise FitError("points: a run needs two distinct vertices")
    if len(q) == 2 or _turning_rad(np.diff(q, axis=0)).max() < 1e-12:
        return _straight_curve(q)
    limit = len(q) + 8 if max_control_points is None else max_control_points
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    interior = _first_knots(q, s, tolerance_mm)
    target = TARGET_FRACTION * tolerance_mm
    u_guess = s
    for _ in range(MAX_ROUNDS):
        fit = least_squares_fit(q, s, interior)
        knots = _clamped_knots(interior, float(s[-1]))
        bad = fit.u[fit.off_path_mm > target]  # the cheap estimate first: a round it fails needs no foot points
        if not len(bad):
            curve = _curve(fit.control, knots)
            u_vertex, d_vertex, u_sample, d_sample = deviations(curve, q, u_guess=u_guess)
            bad = np.concatenate([u_vertex[d_vertex > target], u_sample[d_sample > target]])
            if not len(bad):
                return curve
            u_guess = u_vertex
        interior = np.unique(np.concatenate([interior, _spans_to_split(knots, bad)]))
        if len(interior) + DEGREE + 1 > limit:
            break
    raise FitError(f"no cubic within {tolerance_mm:g} mm of this run of {len(q)} vertices with at most "
                   f"{limit} control points")


def runs_forward(curve: NurbsCurve, points: ArrayLike, samples_per_segment: int = SAMPLES_PER_SEGMENT) -> bool:
    """True when the curve progresses monotonically along the polyline: the vertices' foot
    points come in order, and at every curve sample the tangent points forward along the
    segment the sample belongs to (x' . (Q_(j+1) - Q_j) > 0): no loop, no turning back."""
    q = distinct_vertices(_as_points(points))
    if len(q) < 2:
        return True
    u_vertex, _, u_sample, _ = deviations(curve, q, samples_per_segment)
    if np.any(np.diff(u_vertex) < 0):
        return False
    own = np.clip(np.searchsorted(u_vertex, u_sample, side="right") - 1, 0, len(q) - 2)
    tangent = curve.derivatives(u_sample, 1)[1]
    return bool(np.all(np.einsum("ij,ij->i", tangent, np.diff(q, axis=0)[own]) > 0))


@dataclass(frozen=True)
class FittedRun:
    """A run of the polyline and the cubic that replaces its segments."""

    span: RunSpan
    curve: NurbsCurve


@dataclass(frozen=True)
class SmoothedPolyline:
    """``fitted``: runs replaced by curves; ``kept``: runs that stay lines (no fit simplified
    them within the tolerance, ``fit_run``'s FitError). Segments outside both stay lines too."""

    fitted: list[FittedRun]
    kept: list[RunSpan]


def smooth_polyline(points: ArrayLike, tolerance_mm: float, feeds_mm_s: ArrayLike | None = None,
                    breaks: ArrayLike | None = None, *, max_segment_mm: float = DEFAULT_MAX_SEGMENT_MM,
                    corner_deg: float = DEFAULT_CORNER_DEG) -> SmoothedPolyline:
    """``smoothable_runs`` (with the tolerance's coarse-vertex rule), then ``fit_run`` on each."""
    pts = _as_points(points)
    fitted, kept = [], []
    for span in smoothable_runs(pts, feeds_mm_s, max_segment_mm=max_segment_mm, corner_deg=corner_deg,
                                breaks=breaks, tolerance_mm=tolerance_mm):
        try:
            fitted.append(FittedRun(span, fit_run(span.vertices(pts), tolerance_mm)))
        except FitError:
            kept.append(span)
    return SmoothedPolyline(fitted, kept)


def curvature_report(curve: NurbsCurve, points: ArrayLike, samples_per_segment: int = SAMPLES_PER_SEGMENT) -> CurvatureReport:
    """Max curvature of the curve (sampled) and the polyline's max Menger curvature over its
    interior vertices."""
    q = distinct_vertices(_as_points(points))
    u = np.linspace(curve.u_min, curve.u_max, samples_per_segment * max(len(q) - 1, 1) + 1)
    kappa_curve = float(np.max(curve.curvature(u)))
    menger = _menger_curvature(q) if len(q) >= 3 else np.zeros(0)
    return CurvatureReport(kappa_curve, float(menger.max(initial=0.0)))
