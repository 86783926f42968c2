"""True chord error of every step of a plan: the largest distance of the program's curve
between two consecutive set-points from the straight chord joining them.

A step inside one block is one *piece* [u_lo, u_hi] of its curve; a step across block
junctions is one piece of every block it touches (all measured against the same chord).
The figure is assigned to the step's end row (row 0: 0).

Straight blocks (2 control points, degree 1) are farthest from a chord at a piece end.
On a curved block every piece is split at the knots; on one knot span the homogeneous curve
A(u) = [C, W] is a polynomial of degree p (NurbsCurve's Taylor coefficients), so with
t = (u - u_lo) / (u_hi - u_lo) in [0, 1] and the chord a-b of length L, direction e:

  Q(t) = C(t) - a W(t)             (W times the offset of x(t) from a: a polynomial in t)
  d(t) = |Q(t) - (Q(t).e) e| / W(t)  (distance from the chord's line)
  tau(t) = Q(t).e / (W(t) L)         (where x(t) projects onto the chord: 0 at a, 1 at b)

d^2 = g / W^2 with g = |Q_perp|^2 is largest where F = g' W - 2 g W' = 0 (F has the sign of
(d^2)'); Newton's method on F from the best of a few samples finds that vertex to rounding,
or ends at a piece end that F points out of (the largest distance there: a corner at a block
junction). The distance at the point found is then evaluated like any curve point. Pieces
where this is not a clean maximum (Newton leaving the sample's bracket or not converging, the
curve projecting beyond the chord's ends by more than PROJECTION_SLACK_MM, a zero-length
chord) are measured by sampling and refining instead (sampled_distances: the former method;
``chord_errors(..., sampled=True)`` measures every curved piece so, the test oracle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.program import Program

SAMPLES_PER_ROUND = 8  # interior samples per refinement round of the sampled search
REFINE_ROUNDS = 3  # rounds after the first: each narrows the bracket by 4.5x
START_SAMPLES = np.linspace(0.0, 1.0, 5)  # Newton starts from the best of these (t in [0, 1])
NEWTON_STEPS = 3
NEWTON_TOLERANCE = 1e-5  # the last Newton step in t: converging quadratically, t is then off by ~1e-10, d by ~1e-19 relative
PROJECTION_SLACK_MM = 1e-11  # x(t) may project beyond the chord's ends by this much (rounding)


# ---- the sampled search (the former method, now the fallback and the test oracle) -------------

def segment_distances(points: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of points (m, k, dim) to the segments a-b (m, dim), clamped to the segment."""
    ab = b - a
    length2 = np.einsum("md,md->m", ab, ab)
    rel = points - a[:, None, :]
    t = np.einsum("mkd,md->mk", rel, ab) / np.where(length2 > 0, length2, 1.0)[:, None]
    t = np.clip(np.where(length2[:, None] > 0, t, 0.0), 0.0, 1.0)
    return np.linalg.norm(rel - t[..., None] * ab[:, None, :], axis=-1)


def sampled_distances(curve, u_lo: NDArray[np.float64], u_hi: NDArray[np.float64], a: NDArray[np.float64],
                      b: NDArray[np.float64]) -> NDArray[np.float64]:
    """For each piece u_lo..u_hi of ``curve``: the largest distance of the curve to chord a-b.

    Samples SAMPLES_PER_ROUND interior parameters, then repeatedly re-samples the bracket
    around the best sample (REFINE_ROUNDS times) and finishes with a parabola through the
    best sample and its neighbours; relative accuracy about 1e-6 on smooth pieces, down to a
    floor of about 1e-14 mm (rounding of the distances).
    """
    m = SAMPLES_PER_ROUND
    lo, hi = np.asarray(u_lo, float), np.asarray(u_hi, float)
    frac = np.arange(1, m + 1) / (m + 1)
    best = np.zeros(len(lo))
    for _ in range(REFINE_ROUNDS + 1):
        u = lo[:, None] + (hi - lo)[:, None] * frac[None, :]
        d = segment_distances(curve.points(u.ravel()).reshape(len(lo), m, -1), a, b)
        k = np.argmax(d, axis=1)
        rows = np.arange(len(lo))
        best = np.maximum(best, d[rows, k])
        step = (hi - lo) / (m + 1)
        centre = u[rows, k]
        # parabolic vertex through the best sample and its neighbours (when both are interior)
        inner = (k > 0) & (k < m - 1)
        if inner.any():
            left, mid, right = d[rows, np.maximum(k - 1, 0)], d[rows, k], d[rows, np.minimum(k + 1, m - 1)]
            denom = left - 2 * mid + right
            shift = np.where(inner & (denom < 0), 0.5 * (left - right) / np.where(denom < 0, denom, -1.0), 0.0)
            centre = centre + np.clip(shift, -1, 1) * step
        lo, hi = np.maximum(centre - step, lo), np.minimum(centre + step, hi)
    u = lo[:, None] + (hi - lo)[:, None] * np.array([0.0, 0.5, 1.0])[None, :]
    d = segment_distances(curve.points(u.ravel()).reshape(len(lo), 3, -1), a, b)
    return np.maximum(best, d.max(axis=1))


def is_line(curve) -> bool:
    return curve.degree == 1 and len(curve.control_points) == 2


@dataclass(frozen=True)
class Pieces:
    """The curve pieces of a plan's steps: piece k is [lo[k], hi[k]] of block[k], measured
    against the chord ending at row[k]."""

    block: NDArray[np.intp]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    row: NDArray[np.intp]

    def select(self, mask: NDArray[np.bool_]) -> "Pieces":
        return Pieces(self.block[mask], self.lo[mask], self.hi[mask], self.row[mask])


def step_pieces(block: NDArray[np.integer], u: NDArray[np.float64], program: Program) -> Pieces:
    """The pieces of every step (module docstring): one per step inside a block, one per block
    touched by a step across junctions."""
    same = block[1:] == block[:-1]
    parts_block = [block[1:][same].astype(np.intp)]
    parts_lo = [np.minimum(u[:-1], u[1:])[same]]
    parts_hi = [np.maximum(u[:-1], u[1:])[same]]
    parts_row = [np.flatnonzero(same) + 1]
    for i in np.flatnonzero(~same) + 1:
        b0, b1 = int(block[i - 1]), int(block[i])
        for b in range(b0, b1 + 1):
            curve = program.blocks[b].curve
            parts_block.append(np.array([b], dtype=np.intp))
            parts_lo.append(np.array([u[i - 1] if b == b0 else curve.u_min]))
            parts_hi.append(np.array([u[i] if b == b1 else curve.u_max]))
            parts_row.append(np.array([i]))
    return Pieces(*(np.concatenate(x) for x in (parts_block, parts_lo, parts_hi, parts_row)))


# ---- the whole program's curves, gathered once --------------------------------------------------

@dataclass(eq=False)
class ProgramCurves:
    """What the chord error needs of every block, as arrays indexed by block: whether it is
    straight, a straight block's end points, weights and parameter range, and every curved
    block's knot spans (Taylor coefficients of A = [C, W] at each span's left knot, padded
    with zeros to the largest degree) in one table, block b's from ``span_offset[b]``."""

    program: Program
    straight: NDArray[np.bool_]
    line_p0: NDArray[np.float64]  # (blocks, dim)
    line_p1: NDArray[np.float64]
    line_w: NDArray[np.float64]  # (blocks, 2)
    line_u: NDArray[np.float64]  # (blocks, 2): u_min, u_max
    breakpoints: list[NDArray[np.float64]]  # per block (empty for straight blocks)
    span_offset: NDArray[np.intp]  # (blocks,)
    span_left: NDArray[np.float64]  # (spans,)
    span_coeffs: NDArray[np.float64]  # (degree + 1, dim + 1, spans)

    @classmethod
    def of(cls, program: Program) -> "ProgramCurves":
        curves = [block.curve for block in program.blocks]
        dim = curves[0].dim if curves else 3
        straight = np.array([is_line(c) for c in curves], dtype=bool)
        n = len(curves)
        p0, p1, w, u = np.zeros((n, dim)), np.zeros((n, dim)), np.ones((n, 2)), np.zeros((n, 2))
        degree = max((c.degree for c, s in zip(curves, straight) if not s), default=1)
        breakpoints: list[NDArray[np.float64]] = []
        offsets, lefts, coeffs, total = np.zeros(n, dtype=np.intp), [], [], 0
        for b, (curve, line) in enumerate(zip(curves, straight)):
            if line:
                p0[b], p1[b] = curve.control_points
                w[b] = curve.weights
                u[b] = curve.u_min, curve.u_max
                breakpoints.append(np.zeros(0))
                continue
            left, c = curve._taylor_coefficients  # (p+1, dim+1, spans)
            padded = np.zeros((degree + 1, dim + 1, c.shape[2]))
            padded[: c.shape[0]] = c
            offsets[b] = total
            total += len(left)
            lefts.append(left)
            coeffs.append(padded)
            breakpoints.append(curve.breakpoints)
        return cls(program, straight, p0, p1, w, u, breakpoints, offsets,
                   np.concatenate(lefts) if lefts else np.zeros(0),
                   np.concatenate(coeffs, axis=2) if coeffs else np.zeros((degree + 1, dim + 1, 0)))

    def line_points(self, block: NDArray[np.intp], u: NDArray[np.float64]) -> NDArray[np.float64]:
        """x(u) on straight (possibly rational) blocks: (1 - s) w0 P0 + s w1 P1 over the weight."""
        u0, u1 = self.line_u[block, 0], self.line_u[block, 1]
        s = np.clip((u - u0) / (u1 - u0), 0.0, 1.0)
        a, b = self.line_w[block, 0] * (1.0 - s), self.line_w[block, 1] * s
        return (a[:, None] * self.line_p0[block] + b[:, None] * self.line_p1[block]) / (a + b)[:, None]


# ---- the vertex search on one knot span ---------------------------------------------------------

@dataclass(frozen=True)
class SpanPieces:
    """Pieces that each lie on one knot span: the span (index into ProgramCurves' table),
    the parameter range, and the row of the chord they are measured against."""

    span: NDArray[np.intp]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    row: NDArray[np.intp]
    block: NDArray[np.intp]

    def select(self, mask: NDArray[np.bool_]) -> "SpanPieces":
        return SpanPieces(self.span[mask], self.lo[mask], self.hi[mask], self.row[mask], self.block[mask])


def split_at_knots(curves: ProgramCurves, pieces: Pieces) -> SpanPieces:
    """Every curved piece (clipped to its curve's range) cut at the knots inside it, so that
    each part lies on one span. The few pieces that cross a knot (a chunk's steps are short)
    are cut and their parts put after the others: each part is measured on its own, so their
    order changes no figure."""
    n = len(pieces.lo)
    lo, hi = pieces.lo.copy(), pieces.hi.copy()
    first = np.zeros(n, dtype=np.intp)
    last = np.zeros(n, dtype=np.intp)
    blocks = np.unique(pieces.block)
    for b in blocks.tolist():
        sel: slice | NDArray[np.bool_] = slice(None) if len(blocks) == 1 else pieces.block == b
        knots = curves.breakpoints[b]
        spans = len(knots) - 2
        lo[sel] = np.clip(lo[sel], knots[0], knots[-1])
        hi[sel] = np.clip(hi[sel], knots[0], knots[-1])
        first[sel] = curves.span_offset[b] + np.clip(np.searchsorted(knots, lo[sel], side="right") - 1, 0, spans)
        last[sel] = curves.span_offset[b] + np.clip(np.searchsorted(knots, hi[sel], side="left") - 1, 0, spans)
    crossing = np.flatnonzero(last > first)
    if not len(crossing):  # no piece crosses a knot
        return SpanPieces(first, lo, hi, pieces.row, pieces.block)
    count = last[crossing] - first[crossing] + 1
    index = np.repeat(crossing, count)
    span = np.repeat(first[crossing], count) + (np.arange(len(index)) - np.repeat(np.cumsum(count) - count, count))
    # inner cuts: a span's left knot, and (before the piece's last span) the next span's left knot
    left = curves.span_left[span]
    right = curves.span_left[np.minimum(span + 1, len(curves.span_left) - 1)]
    part_lo = np.where(span > first[index], left, lo[index])
    part_hi = np.where(span < last[index], right, hi[index])
    keep = last == first
    return SpanPieces(np.concatenate([first[keep], span]), np.concatenate([lo[keep], part_lo]),
                      np.concatenate([hi[keep], part_hi]), np.concatenate([pieces.row[keep], pieces.row[index]]),
                      np.concatenate([pieces.block[keep], pieces.block[index]]))


@dataclass(eq=False)
class Chords:
    """The chord of every part, coordinate-major: start a (dim, n), direction b - a and length L."""

    a: NDArray[np.float64]
    ab: NDArray[np.float64]
    length: NDArray[np.float64]

    @classmethod
    def of(cls, p_by_coordinate: NDArray[np.float64], rows: NDArray[np.intp]) -> "Chords":
        """The chords of the steps ending at ``rows`` of the set-points (dim, N)."""
        a = np.take(p_by_coordinate, rows - 1, axis=1)
        ab = np.take(p_by_coordinate, rows, axis=1) - a
        return cls(a, ab, np.sqrt(np.einsum("dn,dn->n", ab, ab)))


def local_polynomials(curves: ProgramCurves, parts: SpanPieces, chords: Chords) -> NDArray[np.float64]:
    """Per part, the coefficients in t of [Q_perp (dim), Q.e, W] (module docstring):
    (degree + 1, dim + 2, parts)."""
    c = np.take(curves.span_coeffs, parts.span, axis=2)  # (p+1, dim+1, n), in s = u - left
    degree, dim = c.shape[0] - 1, c.shape[1] - 1
    s0 = parts.lo - np.take(curves.span_left, parts.span)
    for k in range(degree):  # Taylor shift to s0: repeated synthetic division
        for j in range(degree - 1, k - 1, -1):
            c[j] += c[j + 1] * s0
    h = parts.hi - parts.lo
    scale = np.ones_like(h)
    for k in range(1, degree + 1):
        scale = scale * h
        c[k] *= scale
    e = chords.ab / np.where(chords.length > 0, chords.length, 1.0)
    out = np.empty((degree + 1, dim + 2, len(h)))
    q = c[:, :dim] - chords.a * c[:, dim:]
    along = np.einsum("kdn,dn->kn", q, e)
    out[:, :dim] = q - along[:, None, :] * e
    out[:, dim] = along
    out[:, dim + 1] = c[:, dim]
    return out


def horner(coeffs: NDArray[np.float64], t: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """Polynomials (degree + 1, m, n) at t (n,) or a number: (m, n)."""
    v = coeffs[-1]
    for j in range(len(coeffs) - 2, -1, -1):
        v = v * t + coeffs[j]
    return v


def horner_2(coeffs: NDArray[np.float64], t: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """Polynomials (degree + 1, m, n) and their first two derivatives at t (n,): each (m, n)."""
    v = coeffs[-1]
    d1 = np.zeros_like(v)
    d2 = np.zeros_like(v)
    for j in range(len(coeffs) - 2, -1, -1):
        d2 = d2 * t + d1
        d1 = d1 * t + v
        v = v * t + coeffs[j]
    return v, d1, 2.0 * d2


def projects_inside(tau: NDArray[np.float64], length: NDArray[np.float64]) -> NDArray[np.bool_]:
    """0 <= tau <= 1 up to PROJECTION_SLACK_MM: x projects onto the chord, not beyond its ends
    (where the distance from the segment would exceed the one from its line)."""
    slack = PROJECTION_SLACK_MM / length
    return (tau >= -slack) & (tau <= 1.0 + slack)


def vertex_parameters(poly: NDArray[np.float64], length: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """t of the largest distance from the chord of every part, and whether that search is
    sound there (module docstring); where it is not, the part must be measured by sampling."""
    dim = poly.shape[1] - 2
    safe_length = np.where(length > 0, length, 1.0)
    ok = length > 0
    best_d2 = np.full(len(length), -1.0)
    t0 = np.zeros(len(length))
    for t in START_SAMPLES:
        v = horner(poly, float(t))
        d2 = np.einsum("dn,dn->n", v[:dim], v[:dim]) / (v[dim + 1] * v[dim + 1])
        ok &= projects_inside(v[dim] / (v[dim + 1] * safe_length), safe_length)
        better = d2 > best_d2
        best_d2 = np.where(better, d2, best_d2)
        t0 = np.where(better, t, t0)
    spacing = START_SAMPLES[1] - START_SAMPLES[0]
    low, high = np.maximum(t0 - spacing, 0.0), np.minimum(t0 + spacing, 1.0)
    q_and_w = poly[:, list(range(dim)) + [dim + 1]]
    t = moved = t0
    for _ in range(NEWTON_STEPS):  # F = g' W - 2 g W' has the sign of (d^2)'; F' = g'' W - g' W' - 2 g W''
        t = moved
        v, d1, d2 = horner_2(q_and_w, t)
        q, q1, q2 = v[:dim], d1[:dim], d2[:dim]
        w, w1, w2 = v[dim], d1[dim], d2[dim]
        g = np.einsum("dn,dn->n", q, q)
        g1 = 2.0 * np.einsum("dn,dn->n", q, q1)
        g2 = 2.0 * (np.einsum("dn,dn->n", q1, q1) + np.einsum("dn,dn->n", q, q2))
        f = g1 * w - 2.0 * g * w1
        f1 = g2 * w - g1 * w1 - 2.0 * g * w2
        concave = f1 < 0
        step = np.where(concave, -f / np.where(concave, f1, -1.0), np.sign(f) * spacing)  # else: uphill
        moved = np.clip(t + step, low, high)
    vertex = concave & (np.abs(step) <= NEWTON_TOLERANCE)
    end = ((t == 0.0) & (f <= 0.0)) | ((t == 1.0) & (f >= 0.0))  # largest at a piece end
    return moved, ok & (vertex | end)


def distances_at(curves: ProgramCurves, parts: SpanPieces, t: NDArray[np.float64] | float,
                 chords: Chords) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Distance of x(u) at u = lo + t (hi - lo) from each part's chord segment (as precise as
    a point evaluation: Horner on the span's own coefficients), and whether x(u) projects
    onto the chord (not beyond its ends)."""
    c = np.take(curves.span_coeffs, parts.span, axis=2)
    dim = c.shape[1] - 1
    v = horner(c, parts.lo + t * (parts.hi - parts.lo) - np.take(curves.span_left, parts.span))
    rel = v[:dim] / v[dim] - chords.a
    safe = np.where(chords.length > 0, chords.length, 1.0)
    along = np.einsum("dn,dn->n", rel, chords.ab) / (safe * safe)
    off = rel - np.clip(along, 0.0, 1.0) * chords.ab
    return np.sqrt(np.einsum("dn,dn->n", off, off)), projects_inside(along, safe)


def raise_at(errors: NDArray[np.float64], rows: NDArray[np.intp], values: NDArray[np.float64]) -> None:
    """errors[rows] = max(errors[rows], values), rows may repeat."""
    np.maximum.at(errors, rows, values)


# ---- the chord error of every step --------------------------------------------------------------

def line_chord_errors(errors: NDArray[np.float64], curves: ProgramCurves, pieces: Pieces,
                      p: NDArray[np.float64]) -> None:
    """Raise ``errors`` at the rows of straight pieces: a straight piece is farthest from the
    chord at one of its ends."""
    for u_end in (pieces.lo, pieces.hi):
        ends = curves.line_points(pieces.block, u_end)
        d = segment_distances(ends[:, None, :], p[pieces.row - 1], p[pieces.row])[:, 0]
        raise_at(errors, pieces.row, d)


def sampled_curve_errors(errors: NDArray[np.float64], program: Program, parts: Pieces | SpanPieces,
                         a: NDArray[np.float64], b: NDArray[np.float64]) -> None:
    """Raise ``errors`` at the rows of curved pieces measured by sampling, block by block."""
    for blk in np.unique(parts.block):
        sel = parts.block == blk
        curve = program.blocks[int(blk)].curve
        lo = np.clip(parts.lo[sel], curve.u_min, curve.u_max)
        hi = np.clip(parts.hi[sel], curve.u_min, curve.u_max)
        raise_at(errors, parts.row[sel], sampled_distances(curve, lo, hi, a[sel], b[sel]))


def point_piece_errors(errors: NDArray[np.float64], program: Program, parts: Pieces | SpanPieces,
                       a: NDArray[np.float64], b: NDArray[np.float64]) -> None:
    """Raise ``errors`` at the rows of pieces of zero parameter length (lo == hi: a step that
    ends or starts on a block's end, such as a rest across a junction): the distance of that
    one point from the chord, bit for bit what the sampled search finds there (all its
    samples are that point)."""
    for blk in np.unique(parts.block):
        sel = parts.block == blk
        curve = program.blocks[int(blk)].curve
        points = curve.points(np.clip(parts.lo[sel], curve.u_min, curve.u_max))
        raise_at(errors, parts.row[sel], segment_distances(points[:, None, :], a[sel], b[sel])[:, 0])


def chord_errors(block: NDArray[np.integer], u: NDArray[np.float64], position_mm: NDArray[np.float64],
                 curves: ProgramCurves, sampled: bool = False) -> NDArray[np.float64]:
    """True chord error of every step, assigned to the step's end row (row 0: 0). ``sampled``:
    every curved piece by sampling (the former method, kept as the test oracle)."""
    n = len(u)
    errors = np.zeros(n)
    program = curves.program
    if n < 2 or not program.blocks:  # no curve (an MDI without motion stands still): no chord
        return errors
    p = np.asarray(position_mm, float)
    pieces = step_pieces(block, u, program)
    on_line = curves.straight[pieces.block]
    if on_line.any():
        line_chord_errors(errors, curves, pieces.select(on_line), p)
    if on_line.all():
        return errors
    curved = pieces.select(~on_line)
    if sampled:
        sampled_curve_errors(errors, program, curved, p[curved.row - 1], p[curved.row])
        return errors
    parts = split_at_knots(curves, curved)
    chords = Chords.of(np.ascontiguousarray(p.T), parts.row)
    t, exact = vertex_parameters(local_polynomials(curves, parts, chords), chords.length)
    d, inside = distances_at(curves, parts, t, chords)
    exact &= inside
    raise_at(errors, parts.row[exact], d[exact])
    if not exact.all():
        rest = parts.select(~exact)
        point = rest.lo == rest.hi
        for measured, pieces_of in ((point_piece_errors, point), (sampled_curve_errors, ~point)):
            if pieces_of.any():
                some = rest.select(pieces_of)
                measured(errors, program, some, p[some.row - 1], p[some.row])
    return errors
