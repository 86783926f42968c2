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
stop; with a jerk limit the smaller of the two); so are zero junction deviation and
reversals. With the jerk filter, a junction speed whose plateau (0.75 v tau either side) would
be shorter than the path grid spacing cannot be held by the filtered motion: the moving
average passes such a point dip about A tau / 4 faster (raw acceleration A either side), so
the junction speed is lowered by that (a stop when nothing is left). As J grows, tau = A / J
and with it the correction vanish: the junction speeds approach those without a jerk limit.
(Before, such a junction was a stop whatever J: with J = 1e12, every corner.) An exact stop splits the program into runs, each planned from rest to rest, and the stop lands on a cycle boundary.

The program adds stops of its own: a block marked ``exact_stop`` (G61, or a dwell, pause or
tool change after it) ends its run, and a G4 dwell before a block holds the axes at rest
``ceil(dwell / T)`` cycles (counted from the last set-point of the arrival to the first
that moves). A block's G64 P tolerance, when tighter than the machine's junction deviation,
is the deviation of the junction into it.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead.path import BlockPiece
from nurbsmotion.planning.lookahead.speed_limits import MARGIN
from nurbsmotion.program import BlockKind, Program
from nurbsmotion.program.records import KINDS, BlockRecords

MIN_BLOCK_LENGTH_MM = 1e-9  # shorter blocks are skipped (no motion)


@dataclass(frozen=True, eq=False)
class Run:
    """Consecutive block pieces planned rest to rest; junction_speed[i] joins piece i and i+1."""

    pieces: tuple[BlockPiece, ...]
    junction_speed_mm_s: tuple[float, ...]
    rest_cycles_before: int = 0  # set-points held at the run's start before it moves (G4 dwell)


def planned_jerk_mm_s3(limits: PlanLimits) -> float | None:
    """The jerk limit the plan is shaped for: None when the acceleration limit already implies
    it. Consecutive second differences within A T^2 each differ by at most 2 A T^2, a jerk of
    2 A / T (5e6 mm/s^3 at A = 2500 mm/s^2, T = 1 ms), so a larger J never binds; the
    set-points are still checked against it (verify.py)."""
    jerk = limits.max_jerk_mm_s3
    if jerk is None or jerk * limits.period_s >= 2.0 * limits.max_accel_mm_s2 * (1.0 + 1e-6):
        return None
    return jerk


def end_tangents(piece: BlockPiece) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents at the start and the end of a piece."""
    d = piece.curve.derivatives(np.array([piece.u_start, piece.u_end]), 1)[1]
    d = d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    return d[0], d[1]


def junction_speed(t_in: np.ndarray, t_out: np.ndarray, limits: PlanLimits, min_pass_mm_s: float = 0.0,
                   deviation_mm: float | None = None) -> float:
    """Largest speed through a junction of unit tangents t_in -> t_out (module docstring);
    ``deviation_mm`` replaces the machine's junction deviation (a block's G64 P)."""
    cos_theta = float(np.clip(np.dot(t_in, t_out), -1.0, 1.0))
    sin_half = math.sqrt(max(0.5 * (1.0 - cos_theta), 0.0))  # sin(theta/2)
    if sin_half <= 1e-12:
        return math.inf
    accel = MARGIN * limits.max_accel_mm_s2
    cos_half = math.sqrt(max(1.0 - sin_half * sin_half, 0.0))  # sin(phi/2), phi = pi - theta
    d = limits.junction_deviation_mm if deviation_mm is None else deviation_mm
    deviation = math.sqrt(accel * d * cos_half / (1.0 - cos_half)) if cos_half < 1 else math.inf
    v = min(deviation, accel * limits.period_s / (2.0 * sin_half))
    stop_below = accel * limits.period_s
    planned_jerk = planned_jerk_mm_s3(limits)
    if planned_jerk is not None:
        jerk = MARGIN * planned_jerk
        v = min(v, jerk * limits.period_s**2 / (2.0 * sin_half))
        stop_below = min(stop_below, jerk * limits.period_s**2)
        if v < min_pass_mm_s:  # no plateau: the filter's average passes the dip A tau / 4 faster
            v -= accel * (limits.max_accel_mm_s2 / planned_jerk) / 4.0
    return v if v > stop_below and d > 0 else 0.0


def program_pieces(program: Program, limits: PlanLimits, first: int = 0, stop: int | None = None) -> list[BlockPiece]:
    """Every block with motion (of blocks ``first`` up to ``stop``), as a whole piece with its feed."""
    pieces = []
    blocks = program.blocks
    for index in range(first, len(blocks) if stop is None else min(stop, len(blocks))):
        block = blocks[index]
        if np.ptp(block.curve.control_points, axis=0).max() <= MIN_BLOCK_LENGTH_MM:
            continue  # every control point in one place: no motion
        feed = limits.feed_for(block.feed_mm_s, rapid=block.kind == BlockKind.RAPID)
        pieces.append(BlockPiece(index, block.curve, block.curve.u_min, block.curve.u_max, feed))
    return pieces


@dataclass(frozen=True)
class ProgramStops:
    """What the program itself asks of the junctions (module docstring)."""

    stop_after: frozenset[int] = frozenset()  # block indices that end at rest
    dwell_s_before: dict[int, float] | None = None  # block index -> G4 dwell before it
    deviation_mm: dict[int, float] | None = None  # block index -> junction deviation into it
    tolerance_mm: dict[int, float] | None = None  # block index -> its G64 P (path tolerance of the corner into it)
    rapids: frozenset[int] = frozenset()  # block indices of rapids (G00): a rapid meeting a feed move is a mode change

    @classmethod
    def of(cls, program: Program, limits: PlanLimits) -> "ProgramStops":
        blocks = program.blocks
        if isinstance(blocks, BlockRecords):  # from the columns: no Block built
            marked = np.flatnonzero(~np.isnan(blocks.blend_tolerances_mm))
            given = dict(zip(marked.tolist(), blocks.blend_tolerances_mm[marked].tolist()))
            stop_after = frozenset(np.flatnonzero(blocks.exact_stops).tolist())
            rapids = frozenset(np.flatnonzero(blocks.kinds == KINDS.index(BlockKind.RAPID)).tolist())
        else:
            given = {i: b.blend_tolerance_mm for i, b in enumerate(blocks) if b.blend_tolerance_mm is not None}
            stop_after = frozenset(i for i, b in enumerate(blocks) if b.exact_stop)
            rapids = frozenset(i for i, b in enumerate(blocks) if b.kind == BlockKind.RAPID)
        deviations = {i: min(p, limits.junction_deviation_mm) for i, p in given.items()}
        return cls(stop_after, program.dwell_s_before(), deviations, given, rapids)

    def mode_change(self, before: int, after: int) -> bool:
        """Whether the corner from block ``before`` into block ``after`` joins a rapid and a feed
        move (LinuxCNC never blends those: tp.c handleModeChange)."""
        return (before in self.rapids) != (after in self.rapids)

    def dwell_between(self, after_block: int, up_to_block: int) -> float:
        """Dwell before the blocks after_block + 1 .. up_to_block (bisected: a call per junction)."""
        if not self.dwell_s_before:
            return 0.0
        blocks, seconds = self.dwells
        return sum(seconds[bisect_right(blocks, after_block):bisect_right(blocks, up_to_block)])

    @cached_property
    def dwells(self) -> tuple[list[int], list[float]]:
        """(block indices in order, the dwell before each)."""
        ordered = sorted((self.dwell_s_before or {}).items())
        return [b for b, _ in ordered], [s for _, s in ordered]


def dwell_cycles(dwell_s: float, period_s: float, after_motion: bool) -> int:
    """Set-points to add for a dwell: a stop already holds one cycle (the run's start repeats
    the arrival point), so after motion ceil(dwell / T) - 1 more, before any motion ceil(dwell / T)."""
    if dwell_s <= 0:
        return 0
    cycles = math.ceil(dwell_s / period_s - 1e-9)
    return max(cycles - 1, 0) if after_motion else cycles


def split_runs(pieces: list[BlockPiece], limits: PlanLimits, min_pass_mm_s: float = 0.0,
               stops: ProgramStops = ProgramStops(), after: BlockPiece | None = None) -> list[Run]:
    """Group pieces into runs separated by exact stops (junctions slower than ``min_pass_mm_s``
    are stops too, and so are the program's own stops and dwells). ``after``: the piece the
    first one follows at rest (pieces set up section by section), None at the program start."""
    runs: list[Run] = []
    current: list[BlockPiece] = []
    speeds: list[float] = []
    rest = 0
    if pieces:
        last = -1 if after is None else after.last_block
        rest = dwell_cycles(stops.dwell_between(last, pieces[0].block), limits.period_s, after is not None)
    arriving = np.zeros(0)  # the end tangent of the piece before (each piece's tangents once)
    for piece in pieces:
        leaving, end = end_tangents(piece)
        if current:
            dwell_s = stops.dwell_between(current[-1].last_block, piece.block)
            deviation = (stops.deviation_mm or {}).get(piece.block)
            v = junction_speed(arriving, leaving, limits, min_pass_mm_s, deviation)
            if v <= 0.0 or dwell_s > 0 or current[-1].last_block in stops.stop_after:
                runs.append(Run(tuple(current), tuple(speeds), rest))
                current, speeds = [], []
                rest = dwell_cycles(dwell_s, limits.period_s, True)
            else:
                speeds.append(v)
        current.append(piece)
        arriving = end
    if current:
        runs.append(Run(tuple(current), tuple(speeds), rest))
    return runs


def trailing_dwell_cycles(pieces: list[BlockPiece], stops: ProgramStops, period_s: float) -> int:
    """Set-points held at the end for a dwell after the last move."""
    last = pieces[-1].last_block if pieces else -1
    return dwell_cycles(stops.dwell_between(last, 1 << 62), period_s, False)


def without_rest(run: Run) -> Run:
    return replace(run, rest_cycles_before=0)
