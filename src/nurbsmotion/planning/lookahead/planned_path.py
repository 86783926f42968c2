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

from dataclasses import replace
from typing import Callable, Sequence

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


def piece_block(program: Program, curve: NurbsCurve, piece: BlockPiece) -> Block:
    """A planned piece as a block of the planned path (``curve``: its trimmed curve)."""
    return Block(BlockKind.NURBS, curve, piece.feed_mm_s, program.blocks[piece.block].source)


def trimmed_curve(piece: BlockPiece) -> tuple[NurbsCurve, UMap]:
    """The curve of just the piece's part and the map from u on the block's curve to u on it:
    a trimmed line or arc as a line or arc of its own; blends and whole blocks as they are."""
    curve = piece.curve
    if piece.corners is not None or (piece.u_start == curve.u_min and piece.u_end == curve.u_max):  # blend, whole
        return curve, lambda u: u
    start, end = curve.points(np.array([piece.u_start, piece.u_end]))
    if piece.u_start == curve.u_min:  # a block's ends are its first and last control points exactly (clamped knots)
        start = curve.control_points[0].copy()
    if piece.u_end == curve.u_max:
        end = curve.end_point
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


def groups(values: NDArray[np.integer]) -> list[tuple[int, NDArray[np.intp]]]:
    """(value, the indices where ``values`` has it, ascending) for each distinct value, the
    values ascending: one stable sort instead of a comparison of all rows per value."""
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    starts = np.flatnonzero(ordered[1:] != ordered[:-1]) + 1
    bounds = [0, *starts.tolist(), len(values)] if len(values) else [0]
    return [(int(ordered[lo]), order[lo:hi]) for lo, hi in zip(bounds[:-1], bounds[1:])]


class PlannedPath:
    """The planned pieces as a Program (``program``) and how set-points move onto it.

    ``streamed``: the pieces of a plan set up section by section (lookahead.PlanStream), made
    blocks of ``program`` as the chunks reach them, so nothing walks the whole program before
    the first chunk. A program with pieces is then always measured on them, blended or not:
    an unblended piece is its block's whole curve (u unchanged, ``on_program`` gives its block
    back), so the figures are those on the program itself."""

    def __init__(self, program: Program, pieces: Sequence[BlockPiece], u_maps: Sequence[UMap], blended: bool,
                 set_up: Callable[[], Sequence[BlockPiece]] | None = None, source: Program | None = None) -> None:
        self.program, self.blended, self.source = program, blended, source  # source: streamed, the program planned
        self.pieces: list[BlockPiece] = list(pieces)
        self.u_maps: list[UMap] = list(u_maps)
        self.set_up = set_up  # streamed: the pieces set up so far (grows), made blocks by ``catch_up``
        self.candidates: dict[int, list[int]] = {}  # block -> the pieces along it (piece_rows)
        self.first_piece = np.full(16, -1, dtype=np.intp)  # block -> its first candidate piece, -1: none (grows)
        self.add_candidates(0)

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
        blocks = tuple(piece_block(program, c, p) for c, p in zip(curves, pieces))
        return cls(Program(program.name, blocks, program.start_position), pieces, maps, True)

    @classmethod
    def streamed(cls, program: Program, set_up: Callable[[], Sequence[BlockPiece]]) -> "PlannedPath":
        """The path of a PlanStream of ``program``: ``set_up`` returns its pieces set up so
        far (PlanStream.pieces_set_up); ``rows`` makes the new ones blocks first."""
        return cls(Program(program.name, [], program.start_position), (), (), True, set_up, program)

    def catch_up(self) -> None:
        """Streamed: the pieces set up since the last call made blocks of ``program``."""
        if self.set_up is None or self.source is None:
            return
        pieces, first = self.set_up(), len(self.pieces)
        blocks = self.program.blocks
        assert isinstance(blocks, list)
        for p in pieces[first:]:
            curve, u_map = trimmed_curve(p)
            blocks.append(piece_block(self.source, curve, p))
            self.pieces.append(p)
            self.u_maps.append(u_map)
        self.add_candidates(first)

    def add_candidates(self, first: int) -> None:
        """Pieces ``first``.. among the candidates of the blocks they lie along."""
        for k in range(first, len(self.pieces)):
            p = self.pieces[k]
            for b in (p.covered.blocks.tolist() if p.covered is not None else [p.block]):
                self.candidates.setdefault(b, []).append(k)
                if len(self.candidates[b]) == 1:
                    self.note_first_piece(b, k)

    def note_first_piece(self, block: int, piece: int) -> None:
        """first_piece[block] = piece, the table doubled until it holds ``block``."""
        while block >= len(self.first_piece):
            self.first_piece = np.concatenate([self.first_piece, np.full(len(self.first_piece), -1, dtype=np.intp)])
        self.first_piece[block] = piece

    def piece_rows(self, trajectory: Trajectory) -> NDArray[np.intp]:
        """Index into ``pieces`` of every set-point: among the pieces along its block (the
        block's own piece, a blend into it, smoothed pieces covering it), the one whose curve
        passes through the set-point at its u."""
        blocks = trajectory.block
        if len(blocks) and (int(blocks.min()) < 0 or int(blocks.max()) >= len(self.first_piece)):
            raise ValueError("a set-point's block has no planned piece")
        rows = self.first_piece[blocks]
        if np.any(rows < 0):
            raise ValueError("a set-point's block has no planned piece")
        for b, at in groups(blocks):
            ks = self.candidates[b]
            if len(ks) < 2:
                continue
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
        self.catch_up()
        if not self.blended or len(trajectory) == 0 or (self.set_up is not None and not self.pieces):
            return trajectory  # streamed without pieces: a program without motion rests on its block 0
        rows = self.piece_rows(trajectory)
        u = trajectory.u.copy()
        for k, at in groups(rows):
            u[at] = self.u_maps[k](trajectory.u[at])
        return replace(trajectory, block=rows.astype(np.int32), u=u)

    def on_program(self, figures: RowFigures) -> RowFigures:
        """Measured rows with their program block again (the trace's ``block`` column: on a
        smoothed piece the block reached); u stays on the planned piece (on a blend: the
        blend's parameter)."""
        if not self.blended or (self.set_up is not None and not self.pieces):
            return figures
        rows = figures.rows
        used = np.unique(rows.block)
        blocks = np.array([self.pieces[k].block for k in used.tolist()], dtype=np.int32)[np.searchsorted(used, rows.block)]
        for k in used.tolist():
            piece = self.pieces[k]
            at = np.flatnonzero(rows.block == k)
            if piece.covered is not None and len(at):
                curve = piece.curve
                whole = piece.u_start == curve.u_min and piece.u_end == curve.u_max
                u = rows.u[at] if whole else piece.u_start + rows.u[at] * (piece.u_end - piece.u_start)  # trimmed line
                blocks[at] = piece.covered.block_at(u)  # the block reached, as the plan reports it
        return replace(figures, rows=replace(rows, block=blocks))
