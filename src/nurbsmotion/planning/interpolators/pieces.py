"""A Program as runs of smooth pieces: where the motion must stop, and what it runs through.

A block's curve is cut at every interior knot of full multiplicity (= degree): there the
curve may have a corner (a polyline as one degree-1 NURBS, a YAML curve with a kink). The
pieces are exact parts of the block's curve with the same parameter, so set-points keep
the block index and u of the program. Consecutive pieces whose tangents turn by more than
the corner angle are separated into runs: the motion stops exactly on that point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nurbsmotion.errors import InputError
from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.program import BlockKind, Program

CORNER_ANGLE_DEG = 1.0  # tangent turn above which a junction is a stop
MIN_PIECE_SIZE_MM = 1e-9  # pieces whose control points all lie this close are skipped
MAX_GAP_MM = 1e-6  # consecutive blocks must meet (Program's contract)


@dataclass(frozen=True)
class Piece:
    block: int  # index of the program block
    curve: NurbsCurve  # the block's curve or an exact part of it (same parameter u)
    feed_mm_s: float


def split_at_full_knots(curve: NurbsCurve) -> list[NurbsCurve]:
    """The curve cut at its interior knots of multiplicity = degree (exact sub-curves)."""
    p, knots = curve.degree, curve.knots
    values, first, counts = np.unique(knots[p + 1: len(knots) - p - 1], return_index=True, return_counts=True)
    cuts = [int(i) + p + 1 for v, i, c in zip(values, first, counts) if c >= p]
    if not cuts:
        return [curve]
    pieces = []
    first_point, head, first_knot = 0, np.zeros(0), 0  # head: the extra leading knot of a later piece
    for m in cuts:
        k = m - 1  # the curve passes through control point k at knots[m]
        piece_knots = np.concatenate([head, knots[first_knot: m + p], [knots[m]]])
        pieces.append(NurbsCurve.create(p, curve.control_points[first_point: k + 1],
                                        curve.weights[first_point: k + 1], piece_knots))
        first_point, head, first_knot = k, knots[m: m + 1], m
    pieces.append(NurbsCurve.create(p, curve.control_points[first_point:], curve.weights[first_point:],
                                    np.concatenate([head, knots[first_knot:]])))
    return pieces


def end_tangents(curve: NurbsCurve) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Tangent directions at the start and the end (the first/last control polygon legs)."""
    points = curve.control_points
    if len(points) == 2:
        d = tuple(float(v) for v in points[1] - points[0])
        return d, d
    return curve.point_and_derivatives(curve.u_min)[1], curve.point_and_derivatives(curve.u_max)[1]


def tangent_angle_deg(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    na, nb = math.sqrt(sum(x * x for x in a)), math.sqrt(sum(x * x for x in b))
    if na == 0.0 or nb == 0.0:
        return 180.0
    cos = sum(x * y for x, y in zip(a, b)) / (na * nb)
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def split_runs(program: Program, limits: PlanLimits, corner_angle_deg: float = CORNER_ANGLE_DEG) -> list[list[Piece]]:
    """The program's pieces grouped into runs between stops. InputError for blocks that do not meet."""
    runs: list[list[Piece]] = []
    previous_end: tuple[float, ...] | None = None
    previous_point = None
    for index, block in enumerate(program.blocks):
        cp = block.curve.control_points
        if np.ptp(cp, axis=0).max() < MIN_PIECE_SIZE_MM:
            continue
        if previous_point is not None:
            gap = float(np.linalg.norm(block.start - previous_point))
            if gap > MAX_GAP_MM:
                raise InputError(str(block.source), f"block starts {gap:.6g} mm away from the end of the block before it")
        feed = limits.feed_for(block.feed_mm_s, rapid=block.kind == BlockKind.RAPID)
        for piece in split_at_full_knots(block.curve):
            if np.ptp(piece.control_points, axis=0).max() < MIN_PIECE_SIZE_MM:
                continue
            start_tangent, end_tangent = end_tangents(piece)
            if previous_end is None or tangent_angle_deg(previous_end, start_tangent) > corner_angle_deg:
                runs.append([])
            runs[-1].append(Piece(index, piece, feed))
            previous_end = end_tangent
        previous_point = block.end
    return runs
