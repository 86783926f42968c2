"""The path a look-ahead plan runs along, as a Program of its own, so planning.measure can
measure set-points on it.

With corner blending (blend.py) a set-point's (block, u) may lie on a blend: a quintic that
replaces the corner into ``block``, with its own parameter u. Measured against the program's
block, its chord error is meaningless (hundreds of um on HSM_test). ``PlannedPath.of`` makes
every planned piece a block (a trimmed line or arc as a line or arc of its own, a blend as its
curve), and ``rows`` moves each set-point onto its piece: block = the piece's index, u on the
piece's curve. Without blends it is the program itself and ``rows`` changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry.corner_blend import arc_of
from nurbsmotion.geometry.nurbs import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve, line_curve
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead.api import planned_pieces
from nurbsmotion.planning.lookahead.path import BlockPiece
from nurbsmotion.planning.measure import RowFigures
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Block, BlockKind, Program

ON_CURVE_MM = 1e-9  # a set-point this close to a blend's curve at its u is on the blend

UMap = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def trimmed_curve(piece: BlockPiece) -> tuple[NurbsCurve, UMap]:
    """The curve of just the piece's part and the map from u on the block's curve to u on it:
    a trimmed line or arc as a line or arc of its own; blends and whole blocks as they are."""
    curve = piece.curve
    if piece.corners is not None or (piece.u_start == curve.u_min and piece.u_end == curve.u_max):  # blend, whole
        return curve, lambda u: u
    start, end = curve.points(np.array([piece.u_start, piece.u_end]))
    if curve.degree == 1:
        span = piece.u_end - piece.u_start
        return line_curve(start, end), lambda u: (np.asarray(u) - piece.u_start) / span
    arc = arc_of(curve)
    if arc is None:  # blend.py trims only lines and planar arcs
        raise ValueError(f"block {piece.block}: a trimmed piece that is neither a line nor an arc")
    s0 = float(curve.arc_length(piece.u_start))
    sweep = (float(curve.arc_length(piece.u_end)) - s0) / arc.radius
    part = arc_curve(arc.center, start, sweep, np.cross(arc.e1, arc.e2), end=end)
    return part, lambda u: np.asarray(part.u_at_arc_length(np.asarray(curve.arc_length(u)) - s0), float)


@dataclass(frozen=True, eq=False)
class PlannedPath:
    """The planned pieces as a Program (``program``) and how set-points move onto it."""

    program: Program
    pieces: tuple[BlockPiece, ...]
    u_maps: tuple[UMap, ...]
    blended: bool

    @classmethod
    def for_algorithm(cls, program: Program, limits: PlanLimits, algorithm: str) -> "PlannedPath":
        """What a plan of ``algorithm`` runs along: lookahead's planned pieces; the program
        itself for the papers' methods, which do not blend."""
        return cls.of(program, limits) if algorithm == "lookahead" else cls(program, (), (), False)

    @classmethod
    def of(cls, program: Program, limits: PlanLimits) -> "PlannedPath":
        pieces = tuple(planned_pieces(program, limits))
        if not any(p.corners is not None or p.covered is not None for p in pieces):
            return cls(program, pieces, (), False)
        curves, maps = zip(*(trimmed_curve(p) for p in pieces))
        blocks = tuple(Block(BlockKind.NURBS, c, p.feed_mm_s, program.blocks[p.block].source)
                       for c, p in zip(curves, pieces))
        return cls(Program(program.name, blocks, program.start_position), pieces, tuple(maps), True)

    def piece_rows(self, trajectory: Trajectory) -> NDArray[np.intp]:
        """Index into ``pieces`` of every set-point: among the pieces along its block (the
        block's own piece, a blend into it, smoothed pieces covering it), the one whose curve
        passes through the set-point at its u."""
        candidates: dict[int, list[int]] = {}
        for k, p in enumerate(self.pieces):
            for b in (p.covered.blocks.tolist() if p.covered is not None else [p.block]):
                candidates.setdefault(b, []).append(k)
        first = {b: ks[0] for b, ks in candidates.items()}
        rows = np.array([first.get(b, -1) for b in trajectory.block.tolist()], dtype=np.intp)
        if np.any(rows < 0):
            raise ValueError("a set-point's block has no planned piece")
        for b, ks in candidates.items():
            if len(ks) < 2:
                continue
            at = np.flatnonzero(trajectory.block == b)
            for k in ks:
                curve = self.pieces[k].curve
                u = trajectory.u[at]
                inside = (u >= curve.u_min) & (u <= curve.u_max)
                points = curve.points(np.clip(u, curve.u_min, curve.u_max))[:, :3]
                on = inside & (np.linalg.norm(points - trajectory.position_mm[at], axis=1) <= ON_CURVE_MM)
                rows[at[on]] = k
                at = at[~on]
                if not len(at):
                    break
        return rows

    def rows(self, trajectory: Trajectory) -> Trajectory:
        """``trajectory`` with every set-point's block and u on ``program`` (the planned pieces)."""
        if not self.blended or len(trajectory) == 0:
            return trajectory
        rows = self.piece_rows(trajectory)
        u = trajectory.u.copy()
        for k in np.unique(rows).tolist():
            at = rows == k
            u[at] = self.u_maps[k](trajectory.u[at])
        return replace(trajectory, block=rows.astype(np.int32), u=u)

    def on_program(self, figures: RowFigures) -> RowFigures:
        """Measured rows with their program block again (the trace's ``block`` column: on a
        smoothed piece the block reached); u stays on the planned piece (on a blend: the
        blend's parameter)."""
        if not self.blended:
            return figures
        rows = figures.rows
        blocks = np.array([p.block for p in self.pieces], dtype=np.int32)[rows.block]
        for k, piece in enumerate(self.pieces):
            at = np.flatnonzero(rows.block == k)
            if piece.covered is not None and len(at):
                curve = piece.curve
                whole = piece.u_start == curve.u_min and piece.u_end == curve.u_max
                u = rows.u[at] if whole else piece.u_start + rows.u[at] * (piece.u_end - piece.u_start)  # trimmed line
                blocks[at] = piece.covered.block_at(u)  # the block reached, as the plan reports it
        return replace(figures, rows=replace(rows, block=blocks))
