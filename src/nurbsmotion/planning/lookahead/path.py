"""The path of a run of blocks as one arc-length grid with its differential geometry.

Each block is sampled on a grid in u, fine where the path turns (at most
``MAX_TURN_RAD`` of tangent turn per interval) and at most ``spacing_mm`` apart. On every
interval the speed sigma(u) = |x'(u)| is the degree-6 polynomial p(r), r = (u - u_k) / h,
through sigma and h sigma' at both ends and sigma at the 3 Gauss-Legendre nodes
(speed_polynomials); the arc length from u_k to any u of the interval is its integral, exact
for polynomial speeds up to degree 6 (the interval lengths agree with the curve's adaptive
quadrature to ~1e-10 relative on the example programs; the tests check the set-points'
steps against that quadrature). At every grid point we keep the
arc-length derivatives of the path (reference §1 derivatives, chain rule with sigma = |x'|):

  t = x_s = x' / sigma,   c = x_ss = (x'' sigma - x' sigma') / sigma^3,
  x_sss = N' / sigma^4 - 3 N sigma' / sigma^5,  N = x'' sigma - x' sigma',
  N' = x''' sigma - x' sigma'',  sigma' = t.x'',  sigma'' = (|x''|^2 + x'.x''' - sigma'^2) / sigma

and du/ds = 1/sigma, d2u/ds2 = -sigma' / sigma^3 for the s -> u table. A block junction is
two grid points at the same s (one per block), so every interval lies inside one block.

Every knot of a block is a grid point; where the curve is only C1 there (degree 2) x_ss
jumps, so each point also keeps the left limits of x_ss, x_sss and d2u/ds2 (x evaluated one
ulp below the knot). The largest |x_ss| on each interval (``kappa_max``) comes from the cubic Hermite
of the curvature vector through both ends (x_ss, x_sss) (interval_curvature_max):
a curve part of arc length L with |x_ss| <= kappa_max lies within kappa_max L^2 / 8 of its
chord (verify.py), which is what the chord-error limit plans and checks.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from threading import Lock
from weakref import WeakKeyDictionary

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.corner_blend import Pieces

MAX_TURN_RAD = 0.02  # tangent turn per grid interval
COARSE_PER_SPAN = 32  # first look at each knot span
GAUSS_POINTS = 3  # per grid interval: intervals are short and inside one knot span (error ~ (h / R)^6 / 2e6)
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(GAUSS_POINTS)
CURVATURE_SAMPLES = np.linspace(0.0, 1.0, 5)
SPEED_DEGREE = 6
TINY_SPEED = 1e-300
BLEND_MIDDLE_U = 0.5  # a blend's curve runs over u in [0, 1] (corner_blend.bezier_curve): its middle


@dataclass(frozen=True, eq=False)
class BlendCorners:
    """The corners a program's blends replace (blend.py): per corner the original incoming and
    outgoing pieces (lines or arcs, exact) and the path tolerance there."""

    incoming: Pieces
    outgoing: Pieces
    tolerance_mm: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Covered:
    """The program blocks a smoothed piece (smoothing.py: merged lines, a fitted curve) runs
    along, in order, and the u on the piece where each of them ends (the last: the piece's end):
    a set-point at u has reached block ``blocks[k]``, k the first with ``u <= u_end[k]``."""

    blocks: NDArray[np.int32]
    u_end: NDArray[np.float64]

    def block_at(self, u: NDArray[np.float64]) -> NDArray[np.int32]:
        k = np.searchsorted(self.u_end, u, side="left")
        return self.blocks[np.minimum(k, len(self.blocks) - 1)]


@dataclass(frozen=True, eq=False)
class ProgramNear:
    """The program's own lines and arcs a piece that is not on the program stands for (a
    smoothed piece, a blend next to one) and the tolerance it keeps from them: verify.py
    measures its set-points against these."""

    pieces: Pieces
    tolerance_mm: float


@dataclass(frozen=True, eq=False)
class BlockPiece:
    """Part [u_start, u_end] of one program block inside a planning window; or a corner blend
    (``corners`` set: its curve replaces corner ``corner`` of them; ``block`` is the outgoing
    block's); or a smoothed piece (``covered`` set: its own curve along several blocks, the
    first of them ``block``; ``deviation_mm``: how far it may be from the program, which the
    blends at its ends leave out of their tolerance). ``feed_out_mm_s``: a blend's feed from
    its middle (u > BLEND_MIDDLE_U) on, where the outgoing block is faster than the incoming
    one (its first half keeps the smaller feed; None: ``feed_mm_s`` throughout), so that
    leaving a slow block (a plunge) speeds up along the blend's second half, which runs near
    the outgoing block and carries its index, as LinuxCNC's blend does along the whole of it
    (blendmath.c: the larger of the two feeds). ``ordinal``: the piece's place in the
    program's list of pieces (-1: not known), which names it where (block, u) does not (a
    blend and its outgoing block share a block)."""

    block: int
    curve: NurbsCurve
    u_start: float
    u_end: float
    feed_mm_s: float
    ordinal: int = -1
    corners: BlendCorners | None = None
    corner: int = -1
    covered: Covered | None = None
    deviation_mm: float = 0.0
    near: ProgramNear | None = None
    feed_out_mm_s: float | None = None

    def slower(self, factor: float) -> BlockPiece:
        """The piece with its feed(s) x factor."""
        out = None if self.feed_out_mm_s is None else self.feed_out_mm_s * factor
        return replace(self, feed_mm_s=self.feed_mm_s * factor, feed_out_mm_s=out)

    def feeds_at(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Feed cap at parameters u: feed_mm_s, and feed_out_mm_s beyond a blend's middle."""
        if self.feed_out_mm_s is None:
            return np.full(len(u), self.feed_mm_s)
        return np.where(u > BLEND_MIDDLE_U, self.feed_out_mm_s, self.feed_mm_s)

    @property
    def last_block(self) -> int:
        """The last program block the piece runs along."""
        return int(self.covered.blocks[-1]) if self.covered is not None else self.block


def set_point_blocks(pieces: tuple[BlockPiece, ...] | list[BlockPiece], piece_index: NDArray[np.int32],
                     u: NDArray[np.float64]) -> NDArray[np.int32]:
    """The program block each set-point (index into ``pieces``, u on that piece) has reached:
    the piece's block, or on a smoothed piece the covered block at u. ``piece_index`` is
    non-decreasing (set-points run forward)."""
    blocks = np.array([piece.block for piece in pieces], dtype=np.int32)[piece_index]
    for k, piece in enumerate(pieces):
        if piece.covered is None:
            continue
        lo, hi = np.searchsorted(piece_index, [k, k + 1])
        if hi > lo:
            blocks[lo:hi] = piece.covered.block_at(u[lo:hi])
    return blocks


@dataclass(eq=False)
class PathGrid:
    """Grid over a run of block pieces; s starts at 0 at the first piece's start."""

    s: NDArray[np.float64]  # (N,) arc length, non-decreasing (junctions repeat s)
    piece: NDArray[np.int32]  # (N,) index into ``pieces``
    u: NDArray[np.float64]  # (N,)
    u_s: NDArray[np.float64]  # (N,) du/ds
    u_ss: NDArray[np.float64]  # (N,) d2u/ds2
    tangent: NDArray[np.float64]  # (N, 3) x_s
    curv: NDArray[np.float64]  # (N, 3) x_ss (curvature vector)
    dcurv: NDArray[np.float64]  # (N, 3) x_sss
    feed_mm_s: NDArray[np.float64]  # (N,) programmed feed of the point's block
    position: NDArray[np.float64]  # (N, 3) x
    pieces: tuple[BlockPiece, ...]
    curv_left: NDArray[np.float64]  # (N, 3) x_ss approached from below (differs from curv at C1 knots)
    dcurv_left: NDArray[np.float64]  # (N, 3) x_sss approached from below
    u_ss_left: NDArray[np.float64]  # (N,) d2u/ds2 approached from below
    kappa_max: NDArray[np.float64]  # (N-1,) largest |x_ss| on each interval (both ends at a junction)
    speed_poly: NDArray[np.float64]  # (SPEED_DEGREE + 1, N-1) coefficients of sigma(r) per interval (zeros at junctions)

    def __len__(self) -> int:
        return len(self.s)

    @property
    def length_mm(self) -> float:
        return float(self.s[-1])

    @property
    def junction(self) -> NDArray[np.bool_]:
        """(N-1,) True for the zero-length intervals between two pieces."""
        return self.piece[1:] != self.piece[:-1]

    @cached_property
    def kappa(self) -> NDArray[np.float64]:
        """(N,) |x_ss|, the curvature (computed once per grid: every planning round reads it)."""
        return row_norms(self.curv)

    @cached_property
    def speed_integral_poly(self) -> NDArray[np.float64]:
        """(SPEED_DEGREE + 1, N-1) coefficients of the integral of sigma(r) over [0, r], divided
        by r: speed_poly[j] / (j + 1) (sampling evaluates it on every set-point)."""
        return self.speed_poly / np.arange(1.0, SPEED_DEGREE + 2.0)[:, None]

    @cached_property
    def interval_mm(self) -> NDArray[np.float64]:
        """(N-1,) arc length of every interval (0 at junctions)."""
        return np.diff(self.s)

    @cached_property
    def interval_u(self) -> NDArray[np.float64]:
        """(N-1,) width of every interval in u (0 at junctions)."""
        return self.u[1:] - self.u[:-1]

    @cached_property
    def interval_u_nonzero(self) -> NDArray[np.float64]:
        """interval_u with 1 where it is 0 (a divisor for the place within an interval)."""
        return np.where(self.interval_u > 0, self.interval_u, 1.0)

    @cached_property
    def u_of_s_poly(self) -> NDArray[np.float64]:
        """(6, N-1) coefficients in r = (s - s_k) / h_k of the quintic Hermite of u(s) on every
        interval through u, du/ds and d2u/ds2 at both ends (left limits at the end); zero-length
        intervals get u_k. From the basis h00 = 1 - 10 r^3 + 15 r^4 - 6 r^5, h10 = r - 6 r^3 +
        8 r^4 - 3 r^5, h20 = (r^2 - 3 r^3 + 3 r^4 - r^5) / 2, h01 = 1 - h00, h11 = -4 r^3 + 7 r^4
        - 3 r^5, h21 = (r^3 - 2 r^4 + r^5) / 2."""
        h = self.interval_mm
        u0, u1 = self.u[:-1], self.u[1:]
        d0, d1 = h * self.u_s[:-1], h * self.u_s[1:]
        e0, e1 = 0.5 * h * h * self.u_ss[:-1], 0.5 * h * h * self.u_ss_left[1:]
        du = u1 - u0
        return np.stack([u0, d0, e0, 10.0 * du - 6.0 * d0 - 4.0 * d1 - 3.0 * e0 + e1,
                         -15.0 * du + 8.0 * d0 + 7.0 * d1 + 3.0 * e0 - 2.0 * e1,
                         6.0 * du - 3.0 * d0 - 3.0 * d1 - e0 + e1])

    @cached_property
    def dcurv_normal(self) -> NDArray[np.float64]:
        """(N,) |x_sss less its tangent part|: the path's own normal jerk is this x v^3."""
        along = row_dots(self.dcurv, self.tangent)
        return row_norms(self.dcurv - along[:, None] * self.tangent)


def row_dots(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """a_i . b_i of every row of two (N, k) arrays (three columns: column by column, 2x
    faster than einsum on (N, 3))."""
    if a.ndim == 2 and a.shape[1] == 3:
        return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]
    return np.einsum("ij,ij->i", a, b)


def row_norms(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """|a_i| of every row of an (N, k) array (three columns: summed column by column, 1.5x
    faster than einsum on (N, 3))."""
    if a.ndim == 2 and a.shape[1] == 3:
        x, y, z = a[:, 0], a[:, 1], a[:, 2]
        return np.sqrt(x * x + y * y + z * z)
    return np.sqrt(np.einsum("ij,ij->i", a, a))


def row_max(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Largest entry of every row of an (N, k) array, column by column (numpy's reduction
    over a short last axis is several times slower)."""
    out = a[:, 0].copy()
    for j in range(1, a.shape[1]):
        np.maximum(out, a[:, j], out=out)
    return out


def coarse_u(curve: NurbsCurve, u_start: float, u_end: float, per_span: int = COARSE_PER_SPAN) -> NDArray[np.float64]:
    """``per_span`` equal steps in u on every knot span between u_start and u_end (knots included)."""
    knots = curve.breakpoints
    edges = np.concatenate([[u_start], knots[(knots > u_start) & (knots < u_end)], [u_end]])
    frac = np.linspace(0.0, 1.0, per_span + 1)[:-1]
    return np.append((edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * frac[None, :]).ravel(), u_end)


COARSE_MEMO_ENTRIES = 4  # coarse looks kept per curve (a long block cut into windows asks for new ones)
_COARSE_MEMO: "WeakKeyDictionary[NurbsCurve, dict[tuple[float, float, int], CoarseLook]]" = WeakKeyDictionary()
_COARSE_LOCK = Lock()


@dataclass(frozen=True, eq=False)
class CoarseLook:
    """x and x' of a curve at coarse_u: what sizing a window (coarse_lengths) and placing the
    grid (piece_u_grid) both start from, evaluated once per curve part."""

    u: NDArray[np.float64]
    x: NDArray[np.float64]  # (n, dim)
    dx: NDArray[np.float64]  # (n, dim) x'(u)

    @cached_property
    def lengths(self) -> NDArray[np.float64]:
        """Polyline length from the first point to each point."""
        return np.concatenate([[0.0], np.cumsum(row_norms(np.diff(self.x, axis=0)))])


def coarse_look(curve: NurbsCurve, u_start: float, u_end: float, per_span: int = COARSE_PER_SPAN) -> CoarseLook:
    """x and x' at coarse_u(curve, u_start, u_end, per_span), memoised on the curve: the
    first window of a run sizes itself on the same part that short_run_plan measured and that
    the grid starts from (the same numbers: a pure function of its arguments)."""
    key = (u_start, u_end, per_span)
    with _COARSE_LOCK:  # plans may run in several threads (the daemon's streamed job, a CLI plan)
        look = _COARSE_MEMO.setdefault(curve, {}).get(key)
    if look is not None:
        return look
    u = coarse_u(curve, u_start, u_end, per_span)
    x, dx = curve.derivatives(u, 1)
    look = CoarseLook(u, x, dx)
    with _COARSE_LOCK:
        memo = _COARSE_MEMO.setdefault(curve, {})
        if len(memo) >= COARSE_MEMO_ENTRIES:
            del memo[next(iter(memo))]
        memo[key] = look
    return look


def coarse_lengths(curve: NurbsCurve, u_start: float, u_end: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, approximate arc length from u_start) on a coarse polyline (COARSE_PER_SPAN points per
    knot span): enough to size look-ahead windows, without the curve's exact quadrature."""
    look = coarse_look(curve, u_start, u_end)
    return look.u, look.lengths


def _speed_fit() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The matrix taking [sigma(0), sigma'(0), sigma(r_1..r_3), sigma(1), sigma'(1)] (r the
    Gauss nodes on [0, 1], derivatives in r) to the coefficients of p(r), and the weights of
    the integral of p over [0, 1]."""
    nodes = (1.0 + _GL_NODES) / 2.0
    powers = np.arange(SPEED_DEGREE + 1)

    def value(r: float) -> NDArray[np.float64]:
        return np.asarray(r ** powers, dtype=np.float64)

    def slope(r: float) -> NDArray[np.float64]:
        return np.where(powers > 0, powers * r ** np.maximum(powers - 1, 0), 0.0)

    rows = [value(0.0), slope(0.0), *[value(r) for r in nodes], value(1.0), slope(1.0)]
    return np.linalg.inv(np.array(rows)), np.asarray(1.0 / (powers + 1.0), dtype=np.float64)


SPEED_FIT, SPEED_INTEGRAL = _speed_fit()


def speed_polynomials(curve: NurbsCurve, u: NDArray[np.float64], sigma: NDArray[np.float64],
                      dsigma: NDArray[np.float64], dsigma_left: NDArray[np.float64]) -> NDArray[np.float64]:
    """Coefficients (SPEED_DEGREE + 1, N - 1) of sigma on every interval [u_k, u_k+1] in
    r = (u - u_k) / h (module docstring); sigma' = d sigma / du at the ends (left limit at the end)."""
    h = u[1:] - u[:-1]
    inner = u[None, :-1] + h[None, :] * ((1.0 + _GL_NODES) / 2.0)[:, None]  # (nodes, N - 1): node by node
    data = np.empty((len(SPEED_FIT), len(h)))  # rows: sigma(0), sigma'(0), the nodes, sigma(1), sigma'(1)
    data[0], data[-2] = sigma[:-1], sigma[1:]
    np.multiply(h, dsigma[:-1], out=data[1])
    np.multiply(h, dsigma_left[1:], out=data[-1])
    data[2:-2] = curve.speeds(inner.reshape(-1)).reshape(inner.shape)
    return SPEED_FIT @ data


def interval_lengths(speed_poly: NDArray[np.float64], h: NDArray[np.float64]) -> NDArray[np.float64]:
    """Arc length of every interval: h times the integral of p over [0, 1]."""
    return h * (SPEED_INTEGRAL @ speed_poly)


def piece_u_grid(piece: BlockPiece, spacing_mm: float, from_start_mm: float = 0.0,
                 from_end_mm: float = 0.0) -> NDArray[np.float64]:
    """u values of the grid of one piece: each coarse interval split so that it is at most
    ``spacing_mm`` long and turns at most MAX_TURN_RAD; plus, where > 0, a point at least
    ``from_start_mm`` after the piece's start and one ``from_end_mm`` before its end
    (plateau_points)."""
    curve = piece.curve
    look = coarse_look(curve, piece.u_start, piece.u_end, 2 if curve.degree == 1 else COARSE_PER_SPAN)
    coarse, d = look.u, look.dx
    speed = row_norms(d)
    t = d / np.maximum(speed, TINY_SPEED)[:, None]
    du = np.diff(coarse)
    length = 0.5 * (speed[1:] + speed[:-1]) * du
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", t[1:], t[:-1]), -1.0, 1.0))
    count = np.maximum(np.ceil(np.maximum(length / spacing_mm, turn / MAX_TURN_RAD)), 1).astype(np.int64)
    starts = np.repeat(coarse[:-1], count)
    offsets = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    fine = np.append(starts + np.repeat(du / count, count) * offsets, coarse[-1])
    if from_start_mm <= 0.0 and from_end_mm <= 0.0:
        return fine
    return np.union1d(fine, plateau_points(look, from_start_mm, from_end_mm))


PLATEAU_POINT_MARGIN = 1e-3  # relative: a plateau point's arc length from its end estimated on the coarse polyline


def plateau_points(look: CoarseLook, from_start_mm: float, from_end_mm: float) -> NDArray[np.float64]:
    """u of the points ``from_start_mm`` after the start and ``from_end_mm`` before the end of a
    curve part (those > 0 and inside it), placed on its coarse polyline: a chord is never longer
    than its arc, so the point is at least that far along the curve (exact on a line), less a
    margin for the interpolation within a coarse interval."""
    lengths = look.lengths
    total = float(lengths[-1])
    wanted = [d * (1.0 + PLATEAU_POINT_MARGIN) for d in (from_start_mm, from_end_mm)]
    targets = np.array([wanted[0], total - wanted[1]])
    inside = np.array([from_start_mm > 0.0, from_end_mm > 0.0]) & (targets > 0.0) & (targets < total)
    return np.interp(targets[inside], lengths, look.u)


def arc_length_derivatives(curve: NurbsCurve, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """(x, x_s, x_ss, x_sss, du/ds, d2u/ds2) at each u (module docstring); the vectors as
    (len(u), dim) views of coordinate-major arrays (computed row by row: contiguous)."""
    x, d1, d2, d3 = curve.derivatives_by_coordinate(u, 3)

    def dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.einsum("ij,ij->j", a, b)

    sigma = np.maximum(np.sqrt(dot(d1, d1)), TINY_SPEED)
    u_s = 1.0 / sigma
    t = d1 / sigma
    sigma1 = dot(t, d2)
    sigma2 = (dot(d2, d2) + dot(d1, d3) - sigma1 * sigma1) / sigma
    n = d2 * sigma - d1 * sigma1
    n1 = d3 * sigma - d1 * sigma2
    u_s3 = u_s * u_s * u_s  # products, not powers: numpy's pow is ~7x slower than a multiply
    curv = n * u_s3
    dcurv = (n1 - 3.0 * n * (sigma1 * u_s)) * (u_s3 * u_s)
    return x.T, t.T, curv.T, dcurv.T, u_s, -sigma1 * u_s3


def to_3d(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pad (N, dim<3) arrays to 3 columns (planning is in XYZ)."""
    if a.shape[1] == 3:
        return a
    out = np.zeros((len(a), 3))
    out[:, : min(3, a.shape[1])] = a[:, :3]
    return out


def knot_points(curve: NurbsCurve, u: NDArray[np.float64]) -> NDArray[np.intp]:
    """Indices of the grid points at the curve's interior knots where x_ss may jump (degree
    <= 3; degree >= 4 is C2 or better at simple knots): their left limits differ."""
    if curve.degree > 3:
        return np.zeros(0, dtype=np.intp)
    knots = curve.breakpoints[1:-1]
    nearest = np.clip(np.searchsorted(u, knots), 0, len(u) - 1)
    return nearest[u[nearest] == knots]


def grid_derivatives(curve: NurbsCurve, u: NDArray[np.float64]) -> tuple[tuple[NDArray[np.float64], ...], ...]:
    """arc_length_derivatives at u, and x_ss, x_sss and d2u/ds2 approached from below
    (re-evaluated one ulp below the interior knots, knot_points): one evaluation of the
    curve for both (the same numbers as two: every point is evaluated on its own)."""
    at_knot = knot_points(curve, u)
    both = arc_length_derivatives(curve, np.concatenate([u, np.nextafter(u[at_knot], -np.inf)]))
    n = len(u)
    x, t, curv, dcurv, u_s, u_ss = (a[:n] for a in both)
    if len(at_knot) == 0:
        return (x, t, curv, dcurv, u_s, u_ss), (curv, dcurv, u_ss)
    curv_left, dcurv_left, u_ss_left = curv.copy(), dcurv.copy(), u_ss.copy()
    curv_left[at_knot], dcurv_left[at_knot], u_ss_left[at_knot] = both[2][n:], both[3][n:], both[5][n:]
    return (x, t, curv, dcurv, u_s, u_ss), (curv_left, dcurv_left, u_ss_left)


def interval_curvature_max(s: NDArray[np.float64], curv: NDArray[np.float64], dcurv: NDArray[np.float64],
                           curv_left: NDArray[np.float64], dcurv_left: NDArray[np.float64]) -> NDArray[np.float64]:
    """max |x_ss| on each grid interval, bounded on the cubic Hermite of the curvature vector
    through (x_ss, x_sss) at its start and the left limits at its end: c(r) = A + B r + C r^2 +
    D r^3 on r in [0, 1]; the largest |c| at r = 0, 1/4, ..., 1 plus half the sample spacing
    times a bound of |c'(r)| (|B| + 2|C| + 3|D|)."""
    h = np.diff(s)
    a, c1 = curv[:-1].T, curv_left[1:].T  # coordinate-major (3, N - 1): rows are contiguous
    b, d1 = h * dcurv[:-1].T, h * dcurv_left[1:].T
    c = 3.0 * (c1 - a) - 2.0 * b - d1
    d = 2.0 * (a - c1) + b + d1

    def squared(v: NDArray[np.float64]) -> NDArray[np.float64]:
        return v[0] * v[0] + v[1] * v[1] + v[2] * v[2]

    best = np.maximum(squared(a), squared(c1))
    for r in CURVATURE_SAMPLES[1:-1]:
        best = np.maximum(best, squared(((d * r + c) * r + b) * r + a))
    slope = np.sqrt(squared(b)) + 2.0 * np.sqrt(squared(c)) + 3.0 * np.sqrt(squared(d))
    return np.sqrt(best) + 0.5 * (CURVATURE_SAMPLES[1] - CURVATURE_SAMPLES[0]) * slope


def plateau_reach_mm(pieces: tuple[BlockPiece, ...], plateau_s: float) -> list[tuple[float, float]]:
    """Per piece, how far into it the feed plateau of a slower previous / next piece reaches
    (F_neighbour x plateau_s; 0 where the neighbour is not slower)."""
    feeds = [piece.feed_mm_s for piece in pieces]
    end_feeds = [piece.feed_mm_s if piece.feed_out_mm_s is None else piece.feed_out_mm_s for piece in pieces]
    reach = [(0.0, 0.0)] * len(pieces)
    if plateau_s <= 0.0:
        return reach
    for i, feed in enumerate(feeds):
        before = end_feeds[i - 1] * plateau_s if i > 0 and end_feeds[i - 1] < feed else 0.0
        after = feeds[i + 1] * plateau_s if i + 1 < len(feeds) and feeds[i + 1] < feed else 0.0
        reach[i] = (before, after)
    return reach


def build_grid(pieces: tuple[BlockPiece, ...], spacing_mm: float, feed_step_s: float = 0.0,
               min_spacing_mm: float = 0.0, plateau_s: float = 0.0) -> PathGrid:
    """The grid of a run of pieces (consecutive pieces meet at their ends), at most
    ``spacing_mm`` apart and, with ``feed_step_s``, at most the piece's feed x feed_step_s (not
    below ``min_spacing_mm``): the raw profile is linear in x = v^2 between grid points, so a
    start from rest reaches the feed F no sooner than one interval ds on, at F^2 / (2 ds): with
    the spacing of a program's rapids (0.4-0.8 mm) a 2.54 mm/s cut accelerated at ~8 mm/s^2.

    With ``plateau_s`` > 0, a piece next to a slower one (feed F) also gets a point F x
    plateau_s from their junction: where a slower piece's feed plateau ends
    (speed_limits.feed_plateaus), so that it ends there and not at the next coarse point."""
    keys = ("s", "piece", "u", "u_s", "u_ss", "tangent", "curv", "dcurv", "feed", "position", "curv_left", "dcurv_left",
            "u_ss_left")
    parts: dict[str, list] = {k: [] for k in keys}
    polys: list[NDArray[np.float64]] = []
    offset = 0.0
    reach = plateau_reach_mm(pieces, plateau_s)
    for index, piece in enumerate(pieces):
        spacing = min(spacing_mm, max(piece.feed_mm_s * feed_step_s, min_spacing_mm)) if feed_step_s > 0 else spacing_mm
        u = piece_u_grid(piece, spacing, *reach[index])
        if piece.feed_out_mm_s is not None and u[0] < BLEND_MIDDLE_U < u[-1]:
            u = np.union1d(u, [BLEND_MIDDLE_U])  # the feed steps up there: a grid point on it
        (x, t, curv, dcurv, u_s, u_ss), (curv_left, dcurv_left, u_ss_left) = grid_derivatives(piece.curve, u)
        cubed = u_s * u_s * u_s  # sigma' = -u_ss / u_s^3 (sigma = 1 / u_s is continuous at knots)
        poly = speed_polynomials(piece.curve, u, 1.0 / u_s, -u_ss / cubed, -u_ss_left / cubed)
        polys += [poly, np.zeros((SPEED_DEGREE + 1, 1))]  # the zero-length junction interval after it
        s = offset + np.concatenate([[0.0], np.cumsum(interval_lengths(poly, np.diff(u)))])
        for key, value in (("s", s), ("u", u), ("u_s", u_s), ("u_ss", u_ss), ("u_ss_left", u_ss_left), ("tangent", to_3d(t)),
                           ("curv", to_3d(curv)), ("dcurv", to_3d(dcurv)), ("position", to_3d(x)),
                           ("curv_left", to_3d(curv_left)), ("dcurv_left", to_3d(dcurv_left))):
            parts[key].append(value)
        parts["piece"].append(np.full(len(u), index, dtype=np.int32))
        parts["feed"].append(piece.feeds_at(u))
        offset = float(s[-1])
    cat = {k: np.concatenate(v) if len(v) > 1 else v[0] for k, v in parts.items()}  # one piece: no copies
    kappa_max = interval_curvature_max(cat["s"], cat["curv"], cat["dcurv"], cat["curv_left"], cat["dcurv_left"])
    junction = cat["piece"][1:] != cat["piece"][:-1]
    ends = row_norms(cat["curv"])
    kappa_max[junction] = np.maximum(ends[:-1], ends[1:])[junction]
    speed_poly = np.concatenate(polys[:-1], axis=1) if len(polys) > 2 else polys[0]
    grid = PathGrid(s=cat["s"], piece=cat["piece"], u=cat["u"], u_s=cat["u_s"], u_ss=cat["u_ss"], speed_poly=speed_poly,
                    tangent=cat["tangent"], curv=cat["curv"], dcurv=cat["dcurv"], feed_mm_s=cat["feed"],
                    position=cat["position"], pieces=tuple(pieces), curv_left=cat["curv_left"],
                    dcurv_left=cat["dcurv_left"], u_ss_left=cat["u_ss_left"], kappa_max=kappa_max)
    grid.kappa = ends  # the cached |x_ss|, computed above
    return grid
