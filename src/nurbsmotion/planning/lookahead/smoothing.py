"""Short-segment smoothing (docs/smoothing.md): runs of short G01 lines become fewer, longer
lines and G2 cubic curves within the path tolerance, so the planner runs along them at the
speed their curvature allows instead of turning at every tiny vertex.

A chain is a stretch of consecutive whole G01 line pieces with one programmed feed, no stop or dwell
inside (a block that ends at rest ends the chain and is not part of it), a corner tolerance
> 0 and smoothing on: the block's G64 Q (> 0 on, Q0 off), else ``PlanLimits.smoothing`` at
the corner's path tolerance. Per chain, with t its smallest tolerance:

1. **Merge** (LinuxCNC's naive-CAM merge): vertices are dropped while the chord that replaces
   them stays within MERGE_SHARE (0.1) x t of every dropped vertex. A vertex's distance from a
   segment is convex along each original segment, and every chord point has an original
   segment whose projection on the chord covers it, so the two paths are within that of each
   other both ways. This is what a V-carve needs (camotics_vcarve.ngc: median segment 1.3 um,
   its noise turns by up to 70 deg): a blend or a junction on a micrometre segment is passed
   at a crawl, and the jerk filter makes each such dip cost about A/J.
2. **Fit** (polyline_fit): the merged polyline's runs (segments < 5 mm turning < 30 deg,
   smoothable_runs with the coarse-vertex rule) keep the first and last half of their end
   segments as lines and get one cubic B-spline between (tangent along those half-lines,
   curvature 0 there: G2), within (1 - MERGE_SHARE) x t of the merged polyline, so within t of
   the program. A fit that needs more than FIT_POINTS_SHARE of the run's vertices as control
   points (a polygon at this tolerance) keeps the lines.

The budget is split explicitly: a smoothed line or curve is within MERGE_SHARE x t (merged
lines) or t (fits) of the program; the corner blends at the ends of merged lines get the rest,
t - MERGE_SHARE x t (``BlockPiece.deviation_mm``, blend.corner_tolerances); a fit touches no
blend (its ends are half-lines of the merged polyline). Every smoothed piece names the blocks
it covers (``path.Covered``), so a set-point reports the line it has actually reached.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import polyline_fit as pf
from nurbsmotion.geometry.corner_blend import line_pieces
from nurbsmotion.geometry.nurbs import NurbsCurve
from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead.blend import is_line, program_tolerance
from nurbsmotion.planning.lookahead.path import BlockPiece, Covered, ProgramNear
from nurbsmotion.planning.lookahead.runs import ProgramStops
from nurbsmotion.program import BlockKind, Program

MERGE_SHARE = 0.1  # merged lines within this x the tolerance of the program (J: 0.1 braid 25.6 s, 0.25 26.3 s)
MAX_MERGE = 256  # program segments one merged line replaces at most
FIT_POINTS_SHARE = 0.5  # a fit with more control points than this x the run's vertices keeps the lines
MAX_RUN_SEGMENTS = 5000  # a cut inside a run is a curvature dip to 0 and a blend: with J a crawl


def smoothed_pieces(pieces: list[BlockPiece], program: Program, limits: PlanLimits,
                    stops: ProgramStops) -> list[BlockPiece]:
    """The pieces with every chain merged and fitted (module docstring)."""
    result: list[BlockPiece] = []
    at = 0
    for first, last, tolerance in chains(pieces, program, limits, stops):
        result.extend(pieces[at:first])
        result.extend(smoothed_chain(pieces[first:last + 1], tolerance))
        at = last + 1
    result.extend(pieces[at:])
    return result


def smoothing_tolerance(piece: BlockPiece, program: Program, limits: PlanLimits, stops: ProgramStops) -> float:
    """The smoothing tolerance of a piece (0: not smoothed): its block's G64 Q, else its path
    tolerance (G64 P or the machine's) when ``limits.smoothing``."""
    block = program.blocks[piece.block]
    if block.kind is not BlockKind.LINE or not is_line(piece.curve) or block.exact_stop:
        return 0.0
    q = block.smoothing_tolerance_mm
    if q is not None:
        return q
    return (stops.tolerance_mm or {}).get(piece.block, limits.path_tolerance_mm) if limits.smoothing else 0.0


def chains(pieces: list[BlockPiece], program: Program, limits: PlanLimits,
           stops: ProgramStops) -> list[tuple[int, int, float]]:
    """(first, last piece index, smallest tolerance) of every chain of at least two pieces."""
    out = []
    first, smallest = -1, 0.0
    for i, piece in enumerate(pieces):
        before = pieces[i - 1] if i else None
        tolerance = smoothing_tolerance(piece, program, limits, stops)
        joined = (first >= 0 and tolerance > 0 and before is not None and same_programmed_feed(program, before, piece)
                  and program_tolerance(before.last_block, piece.block, limits, stops) > 0)
        if joined:
            smallest = min(smallest, tolerance)
            continue
        if first >= 0 and i - 1 > first:
            out.append((first, i - 1, smallest))
        first, smallest = (i, tolerance) if tolerance > 0 else (-1, 0.0)
    if first >= 0 and len(pieces) - 1 > first:
        out.append((first, len(pieces) - 1, smallest))
    return out


def same_programmed_feed(program: Program, before: BlockPiece, piece: BlockPiece) -> bool:
    """Both pieces' blocks programmed at one feed. The programmed F, not the feed planned (a
    feed override makes every feed one): the pieces, and with them a Resume's ordinal, must
    not depend on the override."""
    return program.blocks[before.last_block].feed_mm_s == program.blocks[piece.block].feed_mm_s


def merged_vertices(q: NDArray[np.float64], tolerance_mm: float) -> NDArray[np.intp]:
    """Indices of the vertices kept: greedily the farthest next vertex whose chord stays within
    ``tolerance_mm`` of every vertex between (exponential search, then bisection)."""
    keep = [0]
    i, n = 0, len(q) - 1
    while i < n:
        good, step = i + 1, 1
        bad = None
        while good < n and good - i < MAX_MERGE:
            j = min(i + 2 * step, n, i + MAX_MERGE)
            if chord_holds(q, i, j, tolerance_mm):
                good, step = j, 2 * step
                if j == n:
                    break
            else:
                bad = j
                break
        if bad is not None:
            lo, hi = good, bad
            while hi - lo > 1:
                mid = (lo + hi) // 2
                lo, hi = (mid, hi) if chord_holds(q, i, mid, tolerance_mm) else (lo, mid)
            good = lo
        keep.append(good)
        i = good
    return np.array(keep, dtype=np.intp)


def chord_holds(q: NDArray[np.float64], i: int, j: int, tolerance_mm: float) -> bool:
    """Every vertex strictly between i and j within ``tolerance_mm`` of the segment q[i] q[j]."""
    if j - i < 2:
        return True
    a, d = q[i], q[j] - q[i]
    length = float(np.linalg.norm(d))
    if length <= 1e-9:
        return False
    t = d / length
    r = q[i + 1:j] - a
    along = np.clip(r @ t, 0.0, length)
    return bool(np.max(np.linalg.norm(r - along[:, None] * t, axis=1)) <= tolerance_mm)


def smoothed_chain(chain: list[BlockPiece], tolerance_mm: float) -> list[BlockPiece]:
    """One chain's pieces after the merge and the fit (module docstring)."""
    q = np.array([chain[0].curve.control_points[0]] + [p.curve.control_points[-1] for p in chain], float)
    q = np.pad(q, ((0, 0), (0, 3 - q.shape[1]))) if q.shape[1] < 3 else q[:, :3]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    merge = MERGE_SHARE * tolerance_mm
    kept = merged_vertices(q, merge)
    mq, ms = q[kept], s[kept]
    pieces = ChainPieces(chain, q, s, merge)
    spans = [] if len(mq) < 4 else pf.smoothable_runs(mq, tolerance_mm=(1.0 - MERGE_SHARE) * tolerance_mm,
                                                          max_run_segments=MAX_RUN_SEGMENTS)
    at = 0
    for span in spans:
        fit = fitted(mq, span.first, span.last, (1.0 - MERGE_SHARE) * tolerance_mm)
        if fit is None:
            continue
        for k in range(at, span.first):
            pieces.line(mq[k], mq[k + 1], ms[k], ms[k + 1], kept[k + 1] - kept[k] == 1)
        f, last = span.first, span.last
        mid_f, mid_l = 0.5 * (mq[f] + mq[f + 1]), 0.5 * (mq[last - 1] + mq[last])
        smid_f, smid_l = 0.5 * (ms[f] + ms[f + 1]), 0.5 * (ms[last - 1] + ms[last])
        pieces.line(mq[f], mid_f, ms[f], smid_f, False)
        pieces.add(fit, smid_f, smid_l, tolerance_mm)
        pieces.line(mid_l, mq[last], smid_l, ms[last], False)
        at = last
    for k in range(at, len(mq) - 1):
        pieces.line(mq[k], mq[k + 1], ms[k], ms[k + 1], kept[k + 1] - kept[k] == 1)
    return pieces.out


def fitted(mq: NDArray[np.float64], first: int, last: int, tolerance_mm: float) -> NurbsCurve | None:
    """The fit between the middles of the run's end segments, or None (keep the lines)."""
    points = np.concatenate([[0.5 * (mq[first] + mq[first + 1])], mq[first + 1:last],
                             [0.5 * (mq[last - 1] + mq[last])]])
    try:
        curve = pf.fit_run(points, tolerance_mm)
    except pf.FitError:
        return None
    if len(curve.control_points) > FIT_POINTS_SHARE * (last - first + 1) or curve.degree < 3:
        return None
    return curve


class ChainPieces:
    """The smoothed pieces of one chain, built in order, each with the blocks it covers."""

    def __init__(self, chain: list[BlockPiece], q: NDArray[np.float64], s: NDArray[np.float64],
                 merge_mm: float) -> None:
        self.chain, self.q, self.s, self.merge_mm = chain, q, s, merge_mm
        self.blocks = np.array([p.block for p in chain], dtype=np.int32)
        self.out: list[BlockPiece] = []

    def covered(self, s_from: float, s_to: float, u_min: float, u_max: float,
                tolerance_mm: float) -> tuple[Covered, ProgramNear]:
        """Blocks whose segments overlap [s_from, s_to] of the chain's polyline, each ending
        at its vertex's share of the piece's u (arc length along the chain, scaled), and
        those segments as what the piece stands for within ``tolerance_mm``."""
        ends = self.s[1:]
        first = int(np.searchsorted(ends, s_from, side="right"))
        last = max(int(np.searchsorted(self.s[:-1], s_to, side="left")) - 1, first)
        share = (np.clip(ends[first:last + 1], s_from, s_to) - s_from) / max(s_to - s_from, 1e-300)
        u_end = u_min + (u_max - u_min) * share
        u_end[-1] = u_max
        lines = line_pieces(self.q[first:last + 1], self.q[first + 1:last + 2])
        return Covered(self.blocks[first:last + 1].copy(), u_end), ProgramNear(lines, tolerance_mm)

    def line(self, start: NDArray[np.float64], end: NDArray[np.float64], s_from: float, s_to: float,
             original: bool) -> None:
        if original:  # a program segment left as it is
            k = int(np.searchsorted(self.s, s_from, side="right")) - 1
            self.out.append(self.chain[k])
            return
        self.add(line_curve(start, end), s_from, s_to, self.merge_mm)

    def add(self, curve: NurbsCurve, s_from: float, s_to: float, deviation_mm: float) -> None:
        covered, near = self.covered(s_from, s_to, curve.u_min, curve.u_max, deviation_mm)
        self.out.append(BlockPiece(int(covered.blocks[0]), curve, curve.u_min, curve.u_max, self.chain[0].feed_mm_s,
                                   covered=covered, deviation_mm=deviation_mm, near=near))
