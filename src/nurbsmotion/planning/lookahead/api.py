"""The planner's entry points: whole plan, chunks, and re-planning from a moving state."""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, replace
from typing import Iterable, Iterator

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.lookahead import jerk_profile as jp
from nurbsmotion.planning.lookahead.blend import blend_pieces
from nurbsmotion.planning.lookahead.path import BlockPiece, to_3d
from nurbsmotion.planning.lookahead.planner import (FALLBACK_SLOWER, FALLBACK_SPLIT, FALLBACK_STOP, Cursor,
                                                    PlanSettings, PlanningError, WindowPlan, plan_run, settings_for)
from nurbsmotion.planning.lookahead.runs import ProgramStops, Run, dwell_cycles, program_pieces
from nurbsmotion.planning.lookahead.setup import PathSections, max_program_feed
from nurbsmotion.planning.lookahead.sampling import Samples
from nurbsmotion.planning.lookahead.smoothing import smoothed_pieces
from nurbsmotion.planning.lookahead.speed_limits import MARGIN
from nurbsmotion.planning.lookahead.verify import FLUCTUATION_LIMIT, TOLERANCE
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Program

DEFAULT_CHUNK_CYCLES = 2000
WHOLE_PLAN_CHUNK_CYCLES = 20000  # plan_lookahead keeps everything anyway: fewer, longer windows
ALGORITHM = "lookahead"
GUARANTEES = ("chord_error", "accel", "jerk", "axis_velocity", "axis_accel", "arc_fluctuation", "exact_end")


@dataclass(frozen=True)
class PlanState:
    """A moving state along the program: arc length along the planned path (corners blended,
    blend.py) from the program start, speed, acceleration."""

    s_mm: float
    v_mm_s: float = 0.0
    a_mm_s2: float = 0.0


def window_trajectory(plan: WindowPlan, period_s: float, started: float) -> Trajectory:
    feed = plan.planned_ds / period_s
    return Trajectory(algorithm=ALGORITHM, period_s=period_s, block=plan.blocks, u=plan.samples.u.copy(),
                      position_mm=plan.samples.position_mm, feed_mm_s=feed,
                      planning_time_s=time.perf_counter() - started)


class _Figures:
    """Running maxima of the verified figures over all windows, for Trajectory.notes."""

    def __init__(self) -> None:
        self.values: dict[str, float] = {}
        self.repairs = 0
        self.windows = 0
        self.discarded = 0
        self.runs = 0
        self.fallbacks: dict[str, int] = {}

    def add(self, plan: WindowPlan) -> None:
        for key, value in plan.check.figures.items():
            self.values[key] = max(self.values.get(key, 0.0), value)
        self.repairs += plan.repairs
        self.windows += 1
        self.discarded += plan.discarded
        if plan.fallback:
            self.fallbacks[plan.fallback] = self.fallbacks.get(plan.fallback, 0) + 1


def notes_for(limits: PlanLimits, figures: _Figures, runs: int) -> dict[str, float | str]:
    notes: dict[str, float | str] = {
        "guarantees": ", ".join(GUARANTEES),
        "tolerance": TOLERANCE,
        "planning_margin": MARGIN,
        "fluctuation_limit": FLUCTUATION_LIMIT,
        "fluctuation_definition": "arc length between consecutive set-points vs planned step (feed_mm_s * T)",
        "chord_error_limit_mm": limits.chord_error_mm,
        "accel_limit_mm_s2": limits.max_accel_mm_s2,
        "repairs": figures.repairs,  # ints are floats to the notes' type (numeric tower)
        "windows": figures.windows,
        "discarded_windows": figures.discarded,  # window plans thrown away (failed, too short, re-planned)
        "runs": runs,
        "stops": max(runs - 1, 0) + sum(figures.fallbacks.values()) - figures.fallbacks.get(FALLBACK_SLOWER, 0),
        "fallback_stops": figures.fallbacks.get(FALLBACK_STOP, 0) + figures.fallbacks.get(FALLBACK_SPLIT, 0),
        "fallback_slower_blocks": figures.fallbacks.get(FALLBACK_SLOWER, 0),
    }
    if limits.max_jerk_mm_s3 is not None:
        notes["jerk_limit_mm_s3"] = limits.max_jerk_mm_s3
    notes.update({f"verified_{k}": v for k, v in figures.values.items()})
    return notes


@dataclass(frozen=True, eq=False)
class Resume:
    """Where a chunked plan stands after one of its chunks: the last set-point (block, u), the
    three last positions and, while moving, the raw profile's state and the jerk filter's
    memory. Opaque: hand it to plan_lookahead_resumable(..., resume=...) to continue exactly
    (e.g. with a new feed override)."""

    block: int
    u: float
    before: NDArray[np.float64]
    cursor: Cursor | None  # None: at rest there
    tau_f: float
    stop: Trajectory | None = None  # verified set-points from here to rest along the path (None: at rest)
    ordinal: int = -1  # the piece (BlockPiece.ordinal): a corner blend shares its block with the piece after it


def stop_path(plan: WindowPlan, period_s: float) -> Trajectory | None:
    """The set-points after a non-final window's last one that bring the machine to rest on
    the path: the rest of the window's own stop, verified with it (planner.plan_window)."""
    if plan.stop is None:
        return None
    tail = WindowPlan(Samples(plan.stop.samples.piece[len(plan.samples.u):], plan.stop.samples.u[len(plan.samples.u):],
                              plan.stop.samples.position_mm[len(plan.samples.u):]), plan.stop.s[len(plan.samples.u):],
                      plan.stop.planned_ds[len(plan.samples.u):], plan.check, 0, True, None,
                      plan.stop.blocks[len(plan.samples.u):])
    return window_trajectory(tail, period_s, time.perf_counter())


def resume_after(plan: WindowPlan, before: NDArray[np.float64], tau_f: float, period_s: float) -> Resume:
    """Where the plan stands after ``plan``'s last set-point: moving (its cursor, and the
    verified way to stop from there), at a stop the planner made inside a run (its last
    set-point), or at rest at its run's end."""
    run = plan.run
    assert run is not None
    if plan.cursor is not None:
        piece = run.pieces[plan.cursor.piece_index]
        return Resume(piece.block, plan.cursor.u, before, plan.cursor, tau_f, stop_path(plan, period_s), piece.ordinal)
    if plan.early_stop:
        piece = run.pieces[plan.start_piece + int(plan.samples.piece[-1])]
        return Resume(int(plan.blocks[-1]), float(plan.samples.u[-1]), before, None, tau_f, ordinal=piece.ordinal)
    return Resume(run.pieces[-1].block, run.pieces[-1].u_end, before, None, tau_f, ordinal=run.pieces[-1].ordinal)


def rest_chunk(piece: BlockPiece, u: float, point: NDArray[np.float64], cycles: int, period_s: float) -> Trajectory:
    """``cycles`` set-points at rest at ``point`` (a G4 dwell)."""
    return Trajectory(ALGORITHM, period_s, np.full(cycles, piece.block, np.int32), np.full(cycles, u),
                      np.repeat(point.reshape(1, 3), cycles, axis=0), np.zeros(cycles))


def _chunks(runs: Iterable[Run], settings: PlanSettings, first: Cursor | None, figures: _Figures,
            before: NDArray[np.float64] | None = None, trailing_rest: int = 0) -> Iterator[tuple[Trajectory, Resume]]:
    before = np.zeros((0, 3)) if before is None else before
    period = settings.limits.period_s
    last: Run | None = None
    for index, run in enumerate(runs):
        last = run
        started = time.perf_counter()
        cursor = first if index == 0 and first is not None else None
        if run.rest_cycles_before and cursor is None:
            piece = run.pieces[0]
            point = to_3d(piece.curve.points(np.array([piece.u_start])))[0]
            yield (rest_chunk(piece, piece.u_start, point, run.rest_cycles_before, period),
                   Resume(piece.block, piece.u_start, before, None, settings.tau_f, ordinal=piece.ordinal))
        for plan in plan_run(run, settings, before, cursor):
            figures.add(plan)
            if len(plan.samples.u):
                before = np.concatenate([before, plan.samples.position_mm])[-3:]
                yield window_trajectory(plan, period, started), resume_after(plan, before, settings.tau_f, period)
            started = time.perf_counter()
    if trailing_rest and last is not None:
        piece = last.pieces[-1]
        yield (rest_chunk(piece, piece.u_end, before[-1], trailing_rest, period),
               Resume(piece.block, piece.u_end, before, None, settings.tau_f, ordinal=piece.ordinal))


def planned_pieces(program: Program, limits: PlanLimits) -> list[BlockPiece]:
    """The path the planner plans along: the program's blocks with motion, short-segment runs
    smoothed (smoothing.py) and the corners blended within the path tolerance (blend.py). A
    set-point's (block, u) is on one of the pieces along that block (the blend into it, the
    block's own piece, a smoothed piece covering it: u on that piece's curve) whose curve
    passes through it; on a smoothed piece the block is the one reached."""
    return path_pieces(program, limits, ProgramStops.of(program, limits))


def path_pieces(program: Program, limits: PlanLimits, stops: ProgramStops) -> list[BlockPiece]:
    """planned_pieces with the program's stops given: short-segment runs smoothed
    (smoothing.py), then the corners blended (blend.py)."""
    pieces = program_pieces(program, limits)
    return blend_pieces(smoothed_pieces(pieces, program, limits, stops), limits, stops)


@dataclass
class SetUp:
    """What a plan starts from: the runs (set up section by section as they are taken,
    setup.PathSections), the settings, and the set-points of a dwell after the last move."""

    sections: PathSections
    settings: PlanSettings
    trailing: int

    @classmethod
    def of(cls, program: Program, limits: PlanLimits, chunk_cycles: int) -> "SetUp":
        stops = ProgramStops.of(program, limits)
        settings = settings_for(limits, max_program_feed(program, limits), chunk_cycles)
        trailing = dwell_cycles(stops.dwell_between(last_moving_block(program, limits), 1 << 62), limits.period_s, False)
        return cls(PathSections(program, limits, stops, settings.min_pass_mm_s), settings, trailing)


def last_moving_block(program: Program, limits: PlanLimits) -> int:
    """The last block with motion (-1: none): the last piece's last block."""
    for i in range(len(program.blocks) - 1, -1, -1):
        if program_pieces(program, limits, i, i + 1):
            return i
    return -1


def peeked(runs: Iterable[Run]) -> Iterator[Run] | None:
    """``runs`` as an iterator, or None when there are none."""
    it = iter(runs)
    first = next(it, None)
    return None if first is None else itertools.chain([first], it)


def _rest_chunk(program: Program, limits: PlanLimits) -> Trajectory:
    return Trajectory(ALGORITHM, limits.period_s, np.zeros(1, np.int32), np.zeros(1),
                      np.asarray(program.start_position, float).reshape(1, -1)[:, :3], np.zeros(1))


def at_program_line(program: Program, error: PlanningError) -> PlanningError:
    """``error`` with its place as the program's source line (file:line) of its block."""
    if error.block is None or not 0 <= error.block < len(program.blocks):
        return error
    source = program.blocks[error.block].source
    text = f" ({source.text.strip()})" if source.text.strip() else ""
    return PlanningError(str(source), error.message + text, error.block)


def _named_lines(program: Program, chunks: Iterator) -> Iterator:
    """``chunks`` with every PlanningError re-raised at its program line."""
    try:
        yield from chunks
    except PlanningError as error:
        raise at_program_line(program, error) from None


def plan_lookahead_chunks(program: Program, limits: PlanLimits, chunk_cycles: int = DEFAULT_CHUNK_CYCLES,
                          state: PlanState | None = None, _figures: _Figures | None = None) -> Iterator[Trajectory]:
    """The plan in consecutive chunks of roughly ``chunk_cycles`` set-points (see module docs).

    Memory is bounded by the look-ahead window (chunk length + twice the stopping distance
    from the highest feed), not by the program's length."""
    setup = SetUp.of(program, limits, chunk_cycles)
    settings, trailing = setup.settings, setup.trailing
    figures = _figures if _figures is not None else _Figures()
    runs = peeked(_counted(setup.sections.runs(), figures))
    if runs is None:
        yield _rest_chunk(program, limits)
        return
    first = None
    if state is not None:
        listed, first = start_from_state(program, list(runs), state, settings)
        figures.runs = len(listed)
        runs = iter(listed)
    for chunk, _ in _named_lines(program, _chunks(runs, settings, first, figures, trailing_rest=trailing)):
        yield chunk


def _counted(runs: Iterator[Run], figures: _Figures) -> Iterator[Run]:
    """``runs``, each counted in ``figures.runs`` as it is set up."""
    for run in runs:
        figures.runs += 1
        yield run


def plan_lookahead_resumable(program: Program, limits: PlanLimits, chunk_cycles: int = DEFAULT_CHUNK_CYCLES,
                             resume: Resume | None = None) -> Iterator[tuple[Trajectory, Resume]]:
    """Chunks as plan_lookahead_chunks, each with the Resume after it. Given ``resume`` (from an
    earlier plan of the same program), continue from there with ``limits``: the first
    set-point is the one after the resumed chunk's last, and the join is verified against the
    real last set-points and the real filter memory. The acceleration and jerk limits must
    be those of the resumed plan (the filter memory depends on A/J); the feed, chord error and
    axis limits may change."""
    setup = SetUp.of(program, limits, chunk_cycles)
    settings, trailing = setup.settings, setup.trailing
    runs = peeked(setup.sections.runs())
    if runs is None:
        return
    if resume is None:
        yield from _named_lines(program, _chunks(runs, settings, None, _Figures(), trailing_rest=trailing))
        return
    if abs(resume.tau_f - settings.tau_f) > 1e-12:
        raise InputError("limits", "resuming needs the acceleration and jerk limits of the resumed plan "
                         "(the jerk filter's memory depends on A/J); use plan_from_state to re-plan")
    after, first = resume_runs(runs, resume)
    rest = peeked(after)
    if rest is None:
        return
    yield from _named_lines(program, _chunks(rest, settings, first, _Figures(), resume.before, trailing))


def is_resumed_piece(piece: BlockPiece, resume: Resume) -> bool:
    """The piece a Resume stands on: by its ordinal when known (a blend shares its block and
    its range of u with the piece after it), else by block and u."""
    if resume.ordinal >= 0 and piece.ordinal >= 0:
        return piece.ordinal == resume.ordinal
    return piece.block == resume.block and piece.u_start <= resume.u <= piece.u_end


def resume_runs(runs: Iterable[Run], resume: Resume) -> tuple[Iterator[Run], Cursor | None]:
    """The runs from a Resume on, and the cursor that starts the first of them (the runs
    before it are taken from ``runs``, the ones after it are left to be taken)."""
    it = iter(runs)
    for run in it:
        for p, piece in enumerate(run.pieces):
            if not is_resumed_piece(piece, resume):
                continue
            at_piece_end = resume.u >= piece.u_end
            if resume.cursor is None and at_piece_end and p + 1 == len(run.pieces):
                return it, None  # at rest at a run's end: the next run starts there
            if at_piece_end and p + 1 < len(run.pieces):
                p, u = p + 1, run.pieces[p + 1].u_start
            else:
                u = resume.u
            tail = Run(run.pieces[p:], run.junction_speed_mm_s[p:])
            if resume.cursor is None:
                return itertools.chain([tail], it), Cursor(0, u, before=resume.before)
            last = Samples(np.zeros(1, np.int32), np.array([u]), resume.before[-1:], np.zeros(1))
            cursor = replace(resume.cursor, piece_index=0, u=u, run_s_mm=0.0, carry=None, previous=last)
            return itertools.chain([tail], it), cursor
    raise InputError("resume", f"block {resume.block + 1} is not part of this program's motion")


class PlanStream:
    """The plan as a generator of set-point chunks, for consumers that must not hold the
    whole plan (``nurbsmotion plan``, a streaming job): iterate it for the chunks (each with
    the Resume after it when ``with_resume``: where the plan stands and, while moving, the
    verified set-points that stop the machine on the path from the end of that chunk);
    ``notes`` has the guarantees and the verified maxima of the chunks planned so far.

    Memory is one look-ahead window, whatever the program's length.

    ``first_chunk_cycles`` (smaller than ``chunk_cycles``): the first chunk is planned with a
    window of that length and the rest resumed from it (plan_lookahead_resumable's join), so
    a consumer that starts moving on the first chunk waits for a short window only."""

    def __init__(self, program: Program, limits: PlanLimits, chunk_cycles: int = DEFAULT_CHUNK_CYCLES,
                 first_chunk_cycles: int | None = None) -> None:
        self.program, self.limits, self.chunk_cycles = program, limits, chunk_cycles
        self.first_chunk_cycles = first_chunk_cycles
        self.figures = _Figures()
        self.planning_time_s = 0.0
        self.setup: SetUp | None = None

    def chunks(self) -> Iterator[tuple[Trajectory, Resume | None]]:
        started = time.perf_counter()
        self.setup = SetUp.of(self.program, self.limits, self.chunk_cycles)
        runs = peeked(_counted(self.setup.sections.runs(), self.figures))
        if runs is None:
            yield _rest_chunk(self.program, self.limits), None
            return
        for chunk, resume in _named_lines(self.program, self._all_chunks(runs, self.setup.settings, self.setup.trailing)):
            self.planning_time_s += time.perf_counter() - started
            yield chunk, resume
            started = time.perf_counter()
        self.planning_time_s += time.perf_counter() - started

    def _all_chunks(self, runs: Iterator[Run], settings: PlanSettings, trailing: int) -> Iterator[tuple[Trajectory, Resume]]:
        """All chunks; the first with a short window when asked (see the class docstring): the
        runs it took are planned again from its Resume with the full window."""
        first_cycles = self.first_chunk_cycles
        if first_cycles is None or first_cycles >= self.chunk_cycles:
            yield from _chunks(runs, settings, None, self.figures, trailing_rest=trailing)
            return
        taken: list[Run] = []
        short = settings_for(self.limits, settings.max_feed_mm_s, first_cycles)
        first = _chunks(_recorded(runs, taken), short, None, self.figures, trailing_rest=trailing)
        chunk, resume = next(first)
        yield chunk, resume
        after, cursor = resume_runs(itertools.chain(list(taken), runs), resume)
        rest = peeked(after)
        if rest is not None:
            yield from _chunks(rest, settings, cursor, self.figures, resume.before, trailing)
        else:  # the first chunk ended the last run: only a trailing dwell may follow
            yield from first

    @property
    def blocks_set_up(self) -> int:
        """Program blocks whose pieces have been set up so far (setup.PathSections)."""
        return self.setup.sections.blocks_set_up if self.setup is not None else 0

    @property
    def pieces_set_up(self) -> list[BlockPiece]:
        """The planned pieces set up so far, in order (setup.PathSections.pieces): a chunk's
        set-points lie on them."""
        return self.setup.sections.pieces if self.setup is not None else []

    def __iter__(self) -> Iterator[Trajectory]:
        for chunk, _ in self.chunks():
            yield chunk

    @property
    def notes(self) -> dict[str, float | str]:
        return notes_for(self.limits, self.figures, self.figures.runs)


def _recorded(runs: Iterator[Run], taken: list[Run]) -> Iterator[Run]:
    """``runs``, each also appended to ``taken``."""
    for run in runs:
        taken.append(run)
        yield run


def plan_lookahead(program: Program, limits: PlanLimits) -> Trajectory:
    """Plan the whole program (the registered ``lookahead`` algorithm)."""
    started = time.perf_counter()
    figures = _Figures()
    chunks = list(plan_lookahead_chunks(program, limits, WHOLE_PLAN_CHUNK_CYCLES, _figures=figures))
    trajectory = Trajectory.concatenate(chunks)
    trajectory.planning_time_s = time.perf_counter() - started
    trajectory.notes = notes_for(limits, figures, figures.runs)
    return trajectory


def plan_from_state(program: Program, limits: PlanLimits, state: PlanState,
                    chunk_cycles: int = DEFAULT_CHUNK_CYCLES) -> Iterator[Trajectory]:
    """Re-plan from a moving state (e.g. after a feed override): chunks as plan_lookahead_chunks,
    the first set-point one cycle after the state."""
    return plan_lookahead_chunks(program, limits, chunk_cycles, state=state)


def path_point(runs: list[Run], s_mm: float) -> tuple[int, int, float]:
    """(run, piece, u) at arc length s_mm along the runs' pieces (the planned path: corners
    blended; clamped to the path)."""
    remaining = max(s_mm, 0.0)
    for r, run in enumerate(runs):
        for p, piece in enumerate(run.pieces):
            s_start = float(piece.curve.arc_length(piece.u_start))
            length = float(piece.curve.arc_length(piece.u_end)) - s_start
            if remaining <= length or (r == len(runs) - 1 and p == len(run.pieces) - 1):
                return r, p, float(piece.curve.u_at_arc_length(s_start + min(remaining, length)))
            remaining -= length
    raise AssertionError("unreachable")


def start_from_state(program: Program, runs: list[Run], state: PlanState, settings: PlanSettings) -> tuple[list[Run], Cursor]:
    """Runs from the state on and the cursor that starts the first of them moving.

    The jerk filter's memory is seeded with a raw motion of constant acceleration a over the
    last tau_f: raw speed v_r = v + a tau_f / 2, whose average over tau_f is the state."""
    r, p, u = path_point(runs, state.s_mm)
    run = runs[r]
    tail = Run(run.pieces[p:], run.junction_speed_mm_s[p:])
    v, a, tau = state.v_mm_s, state.a_mm_s2, settings.tau_f
    period = settings.limits.period_s
    back = np.array([2.0, 1.0, 0.0]) * period  # the last is the state itself
    before_s = state.s_mm - v * back + 0.5 * a * back**2
    before = np.array([point_at(runs, s) for s in before_s])
    if v <= 0.0 and a <= 0.0:
        return [tail] + runs[r + 1:], Cursor(0, u, before=before)
    if tau > 0:
        v_raw = v + a * tau / 2.0
        offset = v_raw * tau / 2.0 - a * tau**2 / 6.0
        history = jp.RawProfile(t=np.array([-tau, 0.0]), s=np.array([offset - v_raw * tau + a * tau**2 / 2.0, offset]),
                                v=np.array([v_raw - a * tau, v_raw]), a=np.array([a]))
    else:
        v_raw, offset, history = v, 0.0, None
    last = point_at(runs, state.s_mm)
    previous = Samples(np.zeros(1, np.int32), np.array([u]), last[None, :])
    cursor = Cursor(0, u, offset, v_raw, history, before, previous, at_rest=False)
    return [tail] + runs[r + 1:], cursor


def point_at(runs: list[Run], s_mm: float) -> NDArray[np.float64]:
    r, p, u = path_point(runs, s_mm)
    return to_3d(runs[r].pieces[p].curve.points(np.array([u])))[0]
