"""The path's bounding box, verified, so soft limits are checked before any planning.

Every set-point of a job lies on the program's path (the planner samples the blocks' curves,
a stop or a feed override time-scales along them), so the path's extrema bound every
set-point. Each block lies in a box known in closed form (program.records.BlockRecords.boxes_mm:
a line's ends, an arc's or helix' exact extents; a NURBS curve with positive weights lies in
the convex hull of its control points, and so in their box): when the box is inside an axis'
soft limits the block is, and nothing more is computed. Otherwise the
extreme of coordinate x_j is bracketed between a point of the curve (a lower bound, the
value reported) and a verified upper bound: between two curve points a, b with arc length L
between them the curve stays in the ellipsoid with foci a and b and major axis L, whose
extent along axis j is (a_j + b_j)/2 + sqrt((L/2)^2 d_j^2 + ((L/2)^2 - (c/2)^2)(1 - d_j^2))
(c = |b - a|, d the unit chord). Intervals whose bound exceeds the best point found are
split until the bracket is narrower than BRACKET_MM.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.geometry.nurbs import NurbsCurve
from nurbsmotion.program import AXES, Program
from nurbsmotion.program.model import SourceRef
from nurbsmotion.program.records import BlockRecords
from nurbsmotion.service.program_gate import check_machine_can_run

BRACKET_MM = 1e-6  # extremes known to this; far below one count of any real axis
SAMPLES_PER_SPAN = 16
SPLIT = 8
MAX_ROUNDS = 40


@dataclass(frozen=True)
class Extreme:
    """The largest value of sign * x_j on a curve: reached at a curve point, and a verified bound."""

    reached: float  # sign * x_j of a point of the curve
    bound: float  # no point of the curve has sign * x_j above this


def _ellipse_bounds(points: NDArray[np.float64], lengths: NDArray[np.float64], j: int, sign: float) -> NDArray[np.float64]:
    """Upper bound of sign * x_j between consecutive points (module docstring)."""
    a, b = points[:-1], points[1:]
    chord = b - a
    c = np.linalg.norm(chord, axis=1)
    half_l = np.maximum(np.diff(lengths), c) / 2.0
    d_j = np.divide(chord[:, j], c, out=np.zeros_like(c), where=c > 0)
    minor_sq = np.maximum(half_l**2 - (c / 2.0) ** 2, 0.0)
    extent = np.sqrt(half_l**2 * d_j**2 + minor_sq * (1.0 - d_j**2))
    return sign * (a[:, j] + b[:, j]) / 2.0 + extent


def _values(curve: NurbsCurve, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    points = np.atleast_2d(curve.points(u))
    return points, np.atleast_1d(np.asarray(curve.arc_length(u), float))


def curve_extreme(curve: NurbsCurve, j: int, sign: float) -> Extreme:
    """The largest sign * x_j on ``curve`` (sign +1: max, -1: -min), bracketed to BRACKET_MM."""
    hull = float((sign * curve.control_points[:, j]).max())
    ends = float(max(sign * curve.control_points[0, j], sign * curve.control_points[-1, j]))
    if hull - ends <= BRACKET_MM:  # the hull's extreme is an end point: exact
        return Extreme(ends, hull)
    breaks = curve.breakpoints
    u = np.unique(np.concatenate([np.linspace(lo, hi, SAMPLES_PER_SPAN + 1) for lo, hi in zip(breaks[:-1], breaks[1:])]))
    points, lengths = _values(curve, u)
    best = float((sign * points[:, j]).max())
    lo, hi = u[:-1], u[1:]
    bounds = _ellipse_bounds(points, lengths, j, sign)
    for _ in range(MAX_ROUNDS):
        open_ = bounds > best + BRACKET_MM
        if not open_.any():
            break
        lo, hi = lo[open_], hi[open_]
        fine = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, SPLIT + 1)[None, :]
        pts, lens = _values(curve, fine.ravel())
        pts = pts.reshape(len(lo), SPLIT + 1, -1)
        lens = lens.reshape(len(lo), SPLIT + 1)
        best = max(best, float((sign * pts[:, :, j]).max()))
        sub = [_ellipse_bounds(pts[i], lens[i], j, sign) for i in range(len(lo))]
        bounds = np.concatenate(sub)
        lo, hi = fine[:, :-1].ravel(), fine[:, 1:].ravel()
    return Extreme(best, max(best, float(bounds.max(initial=best))))


def block_boxes(program: Program) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(lows, highs), arrays (blocks, dim): per block a box holding its curve. A reader's
    program (program.records) gives them from its columns in closed form, without building a
    curve; other blocks give their control points' min and max (one reduction over all of
    them, np.*.reduceat, not a few per block: a CAM program has ~10^5 blocks)."""
    if isinstance(program.blocks, BlockRecords):
        return program.blocks.boxes_mm()
    points = [block.curve.control_points for block in program.blocks]
    starts = np.cumsum([0] + [len(p) for p in points[:-1]])
    stacked = np.concatenate(points)
    return np.minimum.reduceat(stacked, starts, axis=0), np.maximum.reduceat(stacked, starts, axis=0)


def soft_limit_violation(program: Program, config: MachineConfig, columns: list[int],
                         boxes: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None) -> InputError | None:
    """The first block (in program order) whose path leaves an axis' soft limits, as the error
    of its program line: ``part.nc:42: X650: axis X would reach 650 mm, beyond the soft limit
    600 mm`` (the word only when it is that position, not an arc's bulge). A block whose box
    (``boxes``: block_boxes) is inside every limit is inside: only the others are examined."""
    limited = [(j, axis, col) for j, (axis, col) in enumerate(zip(config.axes, columns)) if axis.soft_limits_mm is not None]
    if not limited or not program.blocks:
        return None
    lows, highs = boxes if boxes is not None else block_boxes(program)
    outside = np.zeros(len(program.blocks), dtype=bool)
    for _, axis, col in limited:
        low, high = axis.soft_limits_mm  # type: ignore[misc]
        outside |= (highs[:, col] > high) | (-lows[:, col] > -low)
    for i in np.flatnonzero(outside).tolist():
        block = program.blocks[i]
        points = block.curve.control_points
        for _, axis, col in limited:
            low, high = axis.soft_limits_mm  # type: ignore[misc]
            for sign, limit in ((1.0, high), (-1.0, low)):
                if (sign * points[:, col]).max() <= sign * limit:
                    continue  # the hull is inside: so is the block
                extreme = curve_extreme(block.curve, col, sign)
                if extreme.reached > sign * limit + BRACKET_MM or extreme.bound > sign * limit + BRACKET_MM:
                    return _violation(block.source, axis.name, sign * extreme.reached, limit)
    return None


def _violation(source: SourceRef, name: str, reached: float, limit: float) -> InputError:
    word = re.search(rf"(?<![A-Za-z]){name}\s*([-+]?(\d+\.?\d*|\.\d+))", source.text, re.IGNORECASE)
    where = str(source)
    if word is not None and abs(float(word.group(1)) - reached) < 1e-6:  # the word is the cause (not a bulge)
        where = f"{source}: {word.group(0).replace(' ', '')}"
    return InputError(where, f"axis {name} would reach {reached:.6g} mm, beyond the soft limit {limit:g} mm")


def moving_unconfigured_axis(program: Program, columns: list[int],
                             boxes: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None) -> int | None:
    """Column of a program axis without a machine axis that some block moves (None: none does);
    the first such block's first such column."""
    if not program.blocks:
        return None
    lows, highs = boxes if boxes is not None else block_boxes(program)
    moved = (highs - lows) > 1e-9
    moved[:, [j for j in columns if j < moved.shape[1]]] = False
    blocks = np.flatnonzero(moved.any(axis=1))
    return int(np.flatnonzero(moved[blocks[0]])[0]) if len(blocks) else None


def path_box(program: Program, columns: list[int],
             boxes: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(min, max) per configured axis over every block's box (block_boxes): a box holding the path."""
    lows, highs = boxes if boxes is not None else block_boxes(program)
    return lows[:, columns].min(axis=0), highs[:, columns].max(axis=0)


def check_before_motion(name: str, program: Program, config: MachineConfig, columns: list[int],
                        axis_map: AxisMap) -> None:
    """Everything about the program knowable without planning it, before any motion: the
    program gate (service.program_gate), a program axis without a machine axis, the soft
    limits from the path's verified bounding box and the int32 count range (InputError)."""
    check_machine_can_run(program, config)
    if not program.blocks:
        raise InputError(name, "the program has no motion")
    boxes = block_boxes(program)
    moved = moving_unconfigured_axis(program, columns, boxes)
    if moved is not None:
        raise InputError(name, f"the program moves {AXES[moved]}, which this machine has no axis for")
    beyond = soft_limit_violation(program, config, columns, boxes)
    if beyond is not None:
        raise beyond
    low, high = path_box(program, columns, boxes)
    try:
        axis_map.to_counts(np.array([low, high]), check_limits=False)
    except InputError as err:
        raise InputError(f"{name}: {err.where}", err.message) from None
