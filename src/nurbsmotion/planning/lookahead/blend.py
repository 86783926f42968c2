"""Corners of the program replaced by curvature-continuous blends within the path tolerance.

Between consecutive pieces that are lines or planar circular arcs (geometry/corner_blend.py),
each corner the machine passes moving becomes a quintic blend: both neighbours are trimmed
by the trim distance d (their u_start / u_end) and the blend piece goes between them, with
the outgoing block's index (source lines and program events still map to blocks in order)
and the smaller of the two feeds, the outgoing one from its middle on where that is faster
(BlockPiece.feed_out_mm_s). The joins are tangent and curvature-continuous, so
split_runs passes them without slowing; the speed on the blend comes from its own curvature
and jerk terms (speed_limits.py).

A corner stays a junction (as before blending) where the program asks for a stop (a block
that ends at rest: G61, a dwell, M0/M1/M6, a spindle wait), where the tolerance is 0 (G64
P0, or ``path_tolerance_mm`` 0), at a near-reversal (deflection above SHARP_LIMIT_DEG), at a
sharp corner (above MAX_DEFLECTION_DEG) whose blend would crawl: one whose speed at its
sharpest (``pass_speed_mm_s``: curvature against A and, with J, the path's jerk at constant
speed) is below SHARP_PASS_SHARE of the faster of its two feeds. Within 0.01 mm a 90 deg
blend passes at ~2 mm/s with J = 50000 and ~8 mm/s without; from 100 mm/s such a crawl costs
as much as a stop and the jerk filter's plateau around it more (grbl's braid 43.7 s with
every corner up to 90 deg blended, 36.9 s up to 30), while on the V-carve's 2.54 mm/s cuts
the same blends pass at nearly the feed (37.74 -> 37.41 s with J, 30.35 -> 30.04 s without).
Rapid-to-feed corners compare the blend with the rapid's feed, so they stay stops, as in
LinuxCNC (tp.c handleModeChange). Without a jerk limit a sharp corner between two blocks of
one feed and one mode (two feed moves or two rapids) is also blended where crossing its blend
costs less than the stop (worth_blending, crossing_loss_s: a 90 deg corner within 0.01 mm from
16.7 to 200 mm/s is). A corner also stays a junction where a piece is not a line
or a planar arc (NURBS blocks, helices), and where no blend passes the shape checks
(corner_blend.trim_distances, monotone). The tolerance of a corner is the outgoing block's
G64 P, else the machine's ``path_tolerance_mm``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import corner_blend as cb
from nurbsmotion.geometry.nurbs import NurbsCurve
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead.path import BlendCorners, BlockPiece, ProgramNear
from nurbsmotion.planning.lookahead.runs import ProgramStops, planned_jerk_mm_s3
from nurbsmotion.planning.lookahead.speed_limits import JERK_SHARE, MARGIN

SHARE_LIMIT = cb.SHARE_LIMIT

MAX_DEFLECTION_DEG = 30.0  # corners turning up to this are blended whatever their blend's speed
SHARP_LIMIT_DEG = 150.0  # sharper corners (near-reversals) stay junctions (corner_blend.middle_deviation's range)
SHARP_PASS_SHARE = 0.8  # a corner above MAX_DEFLECTION_DEG is blended when its blend passes at this x the faster feed
MIN_DEFLECTION_RAD = 1e-9  # tangent already: nothing to blend
MAX_JOIN_ROUNDS = 8  # rounds of CornerPlan.join_short_lines before it gives up joining
JOIN_SMOOTHING = 4  # passes of smoothed() over the joins' curvatures
JOIN_SAME_WAY = 0.5  # cosine between the two corners' binormals above which a joined line turns one way


def pass_speed_mm_s(points: NDArray[np.float64], limits: PlanLimits) -> NDArray[np.float64]:
    """(n,) speed at which blends (control points (n, 6, 3)) can be passed at their sharpest:
    the curvature against A (kappa v^2 <= A) and, with a jerk limit, the jerk of the path at
    constant speed ((kappa^2 + |dc/ds|) v^3 <= JERK_SHARE J), both at MARGIN (speed_limits.py)."""
    kappa, slope = cb.curvature_peaks(points)
    accel = MARGIN * limits.max_accel_mm_s2
    with np.errstate(divide="ignore"):
        v = np.sqrt(accel / kappa)
        jerk = planned_jerk_mm_s3(limits)
        if jerk is not None:
            v = np.minimum(v, np.cbrt(JERK_SHARE * MARGIN * jerk / (kappa * kappa + slope)))
    return v


def crossing_loss_s(points: NDArray[np.float64], feed_mm_s: NDArray[np.float64], accel_mm_s2: float) -> NDArray[np.float64]:
    """(n,) time crossing each blend (control points (n, 6, 3)) costs against cruising at its
    feed F, without a jerk limit: along the blend's curvature samples the speed
    v = min(F, sqrt(A / kappa), sqrt(w^2 + 2 A |s - s_w|)) (its caps, and at A from and to its
    slowest sample w at s_w), each step costing ds (1 / v_mean - 1 / F), and at both ends the ramp
    between v_end and F at A, (F - v_end)^2 / (2 A F). A is on the tangent only (the normal
    acceleration is not charged against it), so this is an estimate, not a bound."""
    c, ds = cb.curvature_samples(points)
    s = np.concatenate([np.zeros((len(points), 1)), np.cumsum(ds, axis=1)], axis=1)
    feed = np.asarray(feed_mm_s, dtype=np.float64)[:, None]
    with np.errstate(divide="ignore"):
        cap = np.minimum(feed, np.sqrt(accel_mm_s2 / np.linalg.norm(c, axis=2)))
    slowest = np.argmin(cap, axis=1)[:, None]
    w, s_w = np.take_along_axis(cap, slowest, axis=1), np.take_along_axis(s, slowest, axis=1)
    v = np.minimum(cap, np.sqrt(w * w + 2.0 * accel_mm_s2 * np.abs(s - s_w)))
    with np.errstate(divide="ignore"):
        inside = np.sum(ds * (2.0 / (v[:, 1:] + v[:, :-1]) - 1.0 / feed), axis=1)
    ramps = ((feed[:, 0] - v[:, 0]) ** 2 + (feed[:, 0] - v[:, -1]) ** 2) / (2.0 * accel_mm_s2 * feed[:, 0])
    return np.asarray(inside + ramps)


def worth_blending(points: NDArray[np.float64], feed_in_mm_s: NDArray[np.float64], feed_out_mm_s: NDArray[np.float64],
                   one_mode: NDArray[np.bool_], limits: PlanLimits, leniency: float = 0.0) -> NDArray[np.bool_]:
    """(n,) which sharp corners' blends (control points (n, 6, 3)) beat a stop. Those that pass
    (pass_speed_mm_s, w) at SHARP_PASS_SHARE of the faster feed at least: a crawl costs as much
    as a stop (with a jerk limit, the filter's plateau around it more); a rapid-to-feed corner
    compares with the rapid's feed, so it stays a stop where the rapid is the faster, as in
    LinuxCNC (tp.c handleModeChange). Without a jerk limit also a corner between two blocks of
    one feed F and one mode (``one_mode``: two feed moves or two rapids) whose blend's crossing (crossing_loss_s) costs less than the stop against
    cruising at F: braking to rest and back at A, F / A, and the corner's set-point held one
    cycle T (grbl's braid: its 90 deg plunge-to-cut corners at 116.7 mm/s, w = 8.6 mm/s, 41 against
    47.7 ms; fusion360_led_floor's at 16.7 mm/s). ``leniency`` > 0 blends more (share and cost
    bound by that fraction: setup.py's margin for a corner that surely stays a stop)."""
    w = pass_speed_mm_s(points, limits)
    feed = np.maximum(feed_in_mm_s, feed_out_mm_s)
    near_feed = w >= SHARP_PASS_SHARE * feed * (1.0 - leniency)
    if planned_jerk_mm_s3(limits) is not None:
        return np.asarray(near_feed)
    accel = MARGIN * limits.max_accel_mm_s2
    stop_s = feed / accel + limits.period_s
    same = (feed_in_mm_s == feed_out_mm_s) & one_mode & (w > 0)
    cheaper = same & (crossing_loss_s(points, feed, accel) < stop_s * (1.0 + leniency))
    return np.asarray(near_feed | cheaper)


def is_line(curve: NurbsCurve) -> bool:
    return curve.degree == 1 and len(curve.control_points) == 2


def piece_shapes(pieces: list[BlockPiece]) -> tuple[cb.Pieces, NDArray[np.bool_]]:
    """Every piece as a line or arc (corner_blend.Pieces, in the pieces' order) and which are
    (whole blocks that are lines or planar circular arcs; the others get placeholder lines)."""
    n = len(pieces)
    start, end = np.zeros((n, 3)), np.zeros((n, 3))
    known = np.zeros(n, dtype=bool)
    arcs: dict[int, cb.Arc] = {}
    for i, piece in enumerate(pieces):
        curve = piece.curve
        if piece.u_start != curve.u_min or piece.u_end != curve.u_max or curve.dim > 3:
            continue
        if is_line(curve):
            start[i, :curve.dim], end[i, :curve.dim] = curve.control_points[0], curve.control_points[1]
            known[i] = True
        else:
            arc = cb.arc_of(curve)
            if arc is not None:
                arcs[i] = arc
                known[i] = True
    shapes = cb.line_pieces(start, end)
    if arcs:
        index = np.fromiter(arcs, dtype=np.intp, count=len(arcs))
        arc_shapes = cb.arc_pieces(list(arcs.values()))
        shapes = cb.Pieces(*(_put(getattr(shapes, f), index, getattr(arc_shapes, f)) for f in cb.PIECE_FIELDS))
    return shapes, known


def _put(a: NDArray, index: NDArray[np.intp], values: NDArray) -> NDArray:
    out = a.copy()
    out[index] = values
    return out


def corner_tolerances(pieces: list[BlockPiece], limits: PlanLimits, stops: ProgramStops) -> NDArray[np.float64]:
    """(n - 1,) path tolerance of every corner between consecutive pieces: the outgoing block's
    G64 P, else the machine's, less what a smoothed piece there already uses of it
    (``BlockPiece.deviation_mm``); 0 where the corner must stay a junction for the program
    (a stop or dwell after the incoming block, or between the two)."""
    out = np.empty(max(len(pieces) - 1, 0))
    for i in range(len(out)):
        before, after = pieces[i].last_block, pieces[i + 1].block
        tolerance = program_tolerance(before, after, limits, stops)
        used = max(pieces[i].deviation_mm, pieces[i + 1].deviation_mm)
        out[i] = max(tolerance - used, 0.0) if tolerance > used else 0.0
    return out


def program_tolerance(before: int, after: int, limits: PlanLimits, stops: ProgramStops) -> float:
    """Path tolerance of the corner from block ``before`` into block ``after``: the outgoing
    block's G64 P, else the machine's; 0 where the program stops or dwells between them."""
    stop = any(b in stops.stop_after for b in range(before, after)) or stops.dwell_between(before, after) > 0
    return 0.0 if stop else (stops.tolerance_mm or {}).get(after, limits.path_tolerance_mm)


def blend_pieces(pieces: list[BlockPiece], limits: PlanLimits, stops: ProgramStops) -> list[BlockPiece]:
    """The pieces with their corners blended (module docstring); every piece's ``ordinal`` set."""
    if len(pieces) < 2:
        return [replace(p, ordinal=i) for i, p in enumerate(pieces)]
    shapes, known = piece_shapes(pieces)
    tolerance = corner_tolerances(pieces, limits, stops)
    n = len(pieces)
    _, t_in, _ = shapes.take(np.arange(n - 1)).state_at(shapes.length_mm[:-1])
    _, t_out, _ = shapes.take(np.arange(1, n)).state_at(np.zeros(n - 1))
    deflection = np.arccos(np.clip(np.einsum("ij,ij->i", t_in, t_out), -1.0, 1.0))
    candidate = (known[:-1] & known[1:] & (tolerance > 0) & (deflection > MIN_DEFLECTION_RAD)
                 & (deflection <= math.radians(SHARP_LIMIT_DEG)))
    corners = np.flatnonzero(candidate)
    if len(corners) == 0:
        return [replace(p, ordinal=i) for i, p in enumerate(pieces)]
    d = cb.trim_distances(shapes.take(corners), shapes.take(corners + 1), tolerance[corners])
    points = cb.blend_points(shapes.take(corners), shapes.take(corners + 1), d)
    good = (d > 0) & cb.monotone(points)
    sharp = deflection[corners] > math.radians(MAX_DEFLECTION_DEG)
    if sharp.any():
        feeds = np.array([(pieces[c].feed_mm_s, pieces[c + 1].feed_mm_s) for c in corners[sharp].tolist()])
        one_mode = np.array([not stops.mode_change(pieces[c].last_block, pieces[c + 1].block)
                             for c in corners[sharp].tolist()], dtype=bool)
        good[sharp] &= worth_blending(points[sharp], feeds[:, 0], feeds[:, 1], one_mode, limits)
    if not good.any():
        return [replace(p, ordinal=i) for i, p in enumerate(pieces)]
    plan = CornerPlan(shapes, corners[good], d[good], tolerance[corners[good]], t_in, t_out, deflection)
    plan.join_short_lines()
    blends = BlendCorners(shapes.take(plan.corners), shapes.take(plan.corners + 1), plan.tolerance)
    return assembled(pieces, plan, blends)


class CornerPlan:
    """The blended corners and where each blend meets its neighbours.

    A blend trims d from both pieces (corner_blend.trim_distances). Where both corners of a
    line are cut short by the lines (SHARE_LIMIT), not by the tolerance, the two blends meet
    at its middle instead
    (``join_short_lines``): the line keeps no piece of its own and both blends share there
    the line's tangent and a curvature vector of their own choice, the smaller of the two
    corners' turn rates (deflection / the mean length of their lines) towards the turn, or 0
    where the path turns the other way after it (an inflection). So a polyline of short lines
    along a curve becomes a G2 chain of blends whose curvature follows the curve, not one
    that returns to 0 on every line. Every such blend is checked like the others (sampled
    distance from its two pieces within the tolerance, monotone); a line next to one that
    fails is not joined (repeated until all pass: then they are the plain blends)."""

    def __init__(self, shapes: cb.Pieces, corners: NDArray[np.intp], d: NDArray[np.float64],
                 tolerance: NDArray[np.float64], t_in: NDArray[np.float64], t_out: NDArray[np.float64],
                 deflection: NDArray[np.float64]) -> None:
        self.shapes, self.corners, self.d, self.tolerance = shapes, corners, d, tolerance
        self.t_in, self.t_out, self.deflection = t_in, t_out, deflection
        n = len(shapes.length_mm)
        self.joined = np.zeros(n, dtype=bool)  # lines whose two blends meet at their middle
        self.curvature = np.zeros((n, 3))  # the blends' curvature vector there
        self.points = cb.blend_points(shapes.take(corners), shapes.take(corners + 1), d)

    def trims(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(cut from the incoming piece's end, cut from the outgoing piece's start) per blend."""
        half = 0.5 * self.shapes.length_mm
        d_in = np.where(self.joined[self.corners], half[self.corners], self.d)
        d_out = np.where(self.joined[self.corners + 1], half[self.corners + 1], self.d)
        return d_in, d_out

    def blend_points(self, index: NDArray[np.intp]) -> NDArray[np.float64]:
        """Control points of blends ``index`` with the current trims and join curvatures."""
        c = self.corners[index]
        d_in, d_out = (v[index] for v in self.trims())
        incoming, outgoing = self.shapes.take(c), self.shapes.take(c + 1)
        p0, t0, k0 = incoming.state_at(incoming.length_mm - d_in)
        p1, t1, k1 = outgoing.state_at(d_out)
        k0 = np.where(self.joined[c][:, None], self.curvature[c], k0)
        k1 = np.where(self.joined[c + 1][:, None], self.curvature[c + 1], k1)
        return cb.control_points(p0, t0, k0, p1, t1, k1)

    def join_short_lines(self) -> None:
        shapes, corners = self.shapes, self.corners
        n = len(shapes.length_mm)
        at = np.full(n, -1)  # blend index of the corner after piece i
        at[corners] = np.arange(len(corners))
        line = ~shapes.is_arc
        length = shapes.length_mm
        capped = self.d >= SHARE_LIMIT * np.minimum(length[corners], length[corners + 1]) * (1.0 - 1e-9)
        inner = np.arange(1, n - 1)
        before, after = at[inner - 1], at[inner]
        ok = line[inner] & (before >= 0) & (after >= 0)
        ok &= capped[np.maximum(before, 0)] & capped[np.maximum(after, 0)]  # the lines, not the tolerance, limit both
        self.joined[inner[ok]] = True
        self.curvature = self.join_curvatures()
        for _ in range(MAX_JOIN_ROUNDS):
            touched = np.flatnonzero(self.joined[corners] | self.joined[corners + 1])
            if len(touched) == 0:
                break
            points = self.blend_points(touched)
            deviation = cb.sampled_deviation(shapes.take(corners[touched]), shapes.take(corners[touched] + 1), points)
            bad = (deviation > cb.TOLERANCE_SHARE * self.tolerance[touched]) | ~cb.monotone(points)
            if not bad.any():
                # every blend from the final trims: those with a joined end were just checked,
                # the others are the plain blends again (a blend whose neighbour was un-joined
                # in an earlier round must not keep points made for the joined trims)
                self.points = self.blend_points(np.arange(len(corners)))
                return
            failed = corners[touched[bad]]
            self.joined[failed] = False
            self.joined[failed + 1] = False
        self.joined[:] = False  # not settled: the plain blends (each checked on its own)
        self.points = cb.blend_points(shapes.take(corners), shapes.take(corners + 1), self.d)

    def join_curvatures(self) -> NDArray[np.float64]:
        """(n, 3) curvature vector at the middle of every joined line (class docstring)."""
        length = self.shapes.length_mm
        turn = np.cross(self.t_in, self.t_out)  # along the binormal, |.| = sin(deflection)
        norm = np.linalg.norm(turn, axis=1)
        binormal = turn / np.maximum(norm, 1e-300)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):  # placeholders of non-line pieces have length 0;
            rate = self.deflection / (0.5 * (length[:-1] + length[1:]))  # only joined lines' corners are used
        out = np.zeros((len(length), 3))
        k = np.flatnonzero(self.joined)
        same_way = np.einsum("ij,ij->i", binormal[k - 1], binormal[k]) > JOIN_SAME_WAY
        k = k[same_way]
        axis = binormal[k - 1] + binormal[k]
        axis /= np.linalg.norm(axis, axis=1)[:, None]
        direction = np.cross(axis, self.shapes.direction[k])
        size = np.zeros(len(length))
        size[k] = np.minimum(rate[k - 1], rate[k])
        out[k] = smoothed(size, k)[:, None] * direction
        return out


def smoothed(size: NDArray[np.float64], k: NDArray[np.intp]) -> NDArray[np.float64]:
    """size at lines k after JOIN_SMOOTHING passes of (1, 2, 1) / 4 along consecutive
    curved joins (a line whose neighbour is not one keeps its share): a CAM polyline's
    noisy turn rates would otherwise step the curvature from blend to blend, and the
    curvature's slope caps the speed with a jerk limit (v^3 |dk/ds| <= J)."""
    curved = np.zeros(len(size) + 2, dtype=bool)
    curved[k + 1] = size[k] > 0
    for _ in range(JOIN_SMOOTHING):
        left = np.where(curved[k], size[k - 1], size[k])
        right = np.where(curved[k + 2], size[np.minimum(k + 1, len(size) - 1)], size[k])
        size = size.copy()
        size[k] = 0.25 * left + 0.5 * size[k] + 0.25 * right
    return size[k]


def trimmed_u(piece: BlockPiece, shape_length_mm: float, sigma_mm: float) -> float:
    """u of the point at arc length sigma along a whole line or arc block."""
    curve = piece.curve
    if is_line(curve):
        return curve.u_min + (curve.u_max - curve.u_min) * sigma_mm / shape_length_mm
    return float(curve.u_at_arc_length(sigma_mm))


def assembled(pieces: list[BlockPiece], plan: CornerPlan, blends: BlendCorners) -> list[BlockPiece]:
    """The pieces trimmed at the blended corners with the blends between them (a joined line
    keeps no piece: its two blends meet at its middle)."""
    shapes = plan.shapes
    d_in, d_out = plan.trims()
    u_start = [p.u_start for p in pieces]
    u_end = [p.u_end for p in pieces]
    for k, c in enumerate(plan.corners.tolist()):
        u_end[c] = trimmed_u(pieces[c], float(shapes.length_mm[c]), float(shapes.length_mm[c] - d_in[k]))
        u_start[c + 1] = trimmed_u(pieces[c + 1], float(shapes.length_mm[c + 1]), float(d_out[k]))
    blend_at = {c: k for k, c in enumerate(plan.corners.tolist())}
    out: list[BlockPiece] = []
    for i, piece in enumerate(pieces):
        if not plan.joined[i]:
            out.append(replace(piece, u_start=u_start[i], u_end=u_end[i], ordinal=len(out)))
        b = blend_at.get(i)
        if b is not None:
            after = pieces[i + 1]
            points = plan.points[b]
            if shapes.is_arc[i] or shapes.is_arc[i + 1]:
                points = exact_ends(points, pieces[i], u_end[i], shapes.is_arc[i], after, u_start[i + 1],
                                    shapes.is_arc[i + 1])
            slower = min(piece.feed_mm_s, after.feed_mm_s)
            out.append(BlockPiece(after.block, cb.bezier_curve(points), 0.0, 1.0, slower,
                                  ordinal=len(out), corners=blends, corner=b,
                                  near=blend_near(piece, after, shapes, i, float(plan.tolerance[b])),
                                  feed_out_mm_s=after.feed_mm_s if after.feed_mm_s > slower else None))
    return out


def blend_near(before: BlockPiece, after: BlockPiece, shapes: cb.Pieces, i: int,
               tolerance_mm: float) -> ProgramNear | None:
    """The program's lines a blend next to a smoothed piece stands for: the smoothed
    neighbours' (``near``), the other neighbour itself; None between two program pieces
    (then its corners are the program's own)."""
    if before.near is None and after.near is None:
        return None
    sides = [p.near.pieces if p.near is not None else shapes.take(np.array([k])) for p, k in ((before, i), (after, i + 1))]
    joined = cb.Pieces(*(np.concatenate([getattr(side, f) for side in sides]) for f in cb.PIECE_FIELDS))
    return ProgramNear(joined, tolerance_mm + max(before.deviation_mm, after.deviation_mm))


def exact_ends(points: NDArray[np.float64], before: BlockPiece, u_before: float, arc_before: bool,
               after: BlockPiece, u_after: float, arc_after: bool) -> NDArray[np.float64]:
    """Control points of a blend at an arc, the arc's end of it from the arc's own evaluation
    at the trim point (position, unit tangent, curvature vector of the NURBS there), so the
    join is G2 to rounding (the analytic arc and the arc's u_at_arc_length agree to ~1e-10
    mm only); a line's end as planned (its point, direction and join curvature)."""
    p0, t0, k0 = cb.end_state(points, start=True)
    p1, t1, k1 = cb.end_state(points, start=False)
    if arc_before:
        p0, t0, k0 = frame(before.curve, u_before)
    if arc_after:
        p1, t1, k1 = frame(after.curve, u_after)
    return cb.control_points(p0[None], t0[None], k0[None], p1[None], t1[None], k1[None])[0]


def frame(curve: NurbsCurve, u: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(point, unit tangent, curvature vector) of a curve at u, in 3-D."""
    x, d1, d2 = (np.pad(v, (0, 3 - curve.dim)) for v in curve.derivatives(u, 2))
    speed = float(np.linalg.norm(d1))
    t = d1 / speed
    k = (d2 - np.dot(d2, t) * t) / (speed * speed)
    return x, t, k
