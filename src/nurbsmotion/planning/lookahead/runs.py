"""The program as runs: stretches of blocks between exact stops, with their junction speeds.

At the junction of two blocks with tangent deflection theta the speed is limited by
- the junction-deviation model (grbl/Klipper): v^2 <= A d sin(phi/2) / (1 - sin(phi/2)) with
  phi = pi - theta the angle between the blocks and d = limits.junction_deviation_mm;
- the discrete second difference: a set-point step turning by theta changes the velocity
  vector by 2 v sin(theta/2) within one cycle, so v <= A T / (2 sin(theta/2));
- with a jerk limit, the discrete third difference: v <= J T^2 / (2 sin(theta/2)).
Tangent-continuous joins (theta = 0) pass without slowing. A junction speed at or below
what one cycle of acceleration (A T) or, with a jerk limit, of jerk (J T^2) gives is an
exact stop (passing that slowly gains nothing: it is the speed of the first cycles after a
stop), and so, with the jerk filter, is a junction speed whose plateau (v tau) would be
shorter than the path grid spacing; so are zero junction deviation and reversals. An exact stop splits the program into runs, each planned from rest to rest, and the stop lands on a cycle boundary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead.path import BlockPiece
from nurbsmotion.planning.lookahead.speed_limits import MARGIN
from nurbsmotion.program import BlockKind, Program

MIN_BLOCK_LENGTH_MM = 1e-9  # shorter blocks are skipped (no motion)


@dataclass(frozen=True, eq=False)
class Run:
    """Consecutive block pieces planned rest to rest; junction_speed[i] joins piece i and i+1."""

    pieces: tuple[BlockPiece, ...]
    junction_speed_mm_s: tuple[float, ...]


def end_tangents(piece: BlockPiece) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents at the start and the end of a piece."""
    d = piece.curve.derivatives(np.array([piece.u_start, piece.u_end]), 1)[1]
    d = d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    return d[0], d[1]


def junction_speed(t_in: np.ndarray, t_out: np.ndarray, limits: PlanLimits, min_pass_mm_s: float = 0.0) -> float:
    """Largest speed through a junction of unit tangents t_in -> t_out (module docstring)."""
    cos_theta = float(np.clip(np.dot(t_in, t_out), -1.0, 1.0))
    sin_half = math.sqrt(max(0.5 * (1.0 - cos_theta), 0.0))  # sin(theta/2)
    if sin_half <= 1e-12:
        return math.inf
    accel = MARGIN * limits.max_accel_mm_s2
    cos_half = math.sqrt(max(1.0 - sin_half * sin_half, 0.0))  # sin(phi/2), phi = pi - theta
    deviation = math.sqrt(accel * limits.junction_deviation_mm * cos_half / (1.0 - cos_half)) if cos_half < 1 else math.inf
    v = min(deviation, accel * limits.period_s / (2.0 * sin_half))
    stop_below = accel * limits.period_s
    if limits.max_jerk_mm_s3 is not None:
        jerk = MARGIN * limits.max_jerk_mm_s3
        v = min(v, jerk * limits.period_s**2 / (2.0 * sin_half))
        stop_below = jerk * limits.period_s**2
    return v if v > max(stop_below, min_pass_mm_s) else 0.0


def program_pieces(program: Program, limits: PlanLimits) -> list[BlockPiece]:
    """Every block with motion, as a whole piece with its feed."""
    pieces = []
    for index, block in enumerate(program.blocks):
        if np.ptp(block.curve.control_points, axis=0).max() <= MIN_BLOCK_LENGTH_MM:
            continue  # every control point in one place: no motion
        feed = limits.feed_for(block.feed_mm_s, rapid=block.kind == BlockKind.RAPID)
        pieces.append(BlockPiece(index, block.curve, block.curve.u_min, block.curve.u_max, feed))
    return pieces


def split_runs(pieces: list[BlockPiece], limits: PlanLimits, min_pass_mm_s: float = 0.0) -> list[Run]:
    """Group pieces into runs separated by exact stops (junctions slower than ``min_pass_mm_s``
    are stops too)."""
    runs: list[Run] = []
    current: list[BlockPiece] = []
    speeds: list[float] = []
    for piece in pieces:
        if current:
            v = junction_speed(end_tangents(current[-1])[1], end_tangents(piece)[0], limits, min_pass_mm_s)
            if v <= 0.0:
                runs.append(Run(tuple(current), tuple(speeds)))
                current, speeds = [], []
            else:
                speeds.append(v)
        current.append(piece)
    if current:
        runs.append(Run(tuple(current), tuple(speeds)))
    return runs
