"""Measure a planned Trajectory against the true path: what the drives would really get.

Every figure is computed from the set-points alone (and the program's true curves), never
from a planner's own estimates, so all algorithms are judged by the same ruler:

- speed of the step ending at row i: |p_i - p_{i-1}| / T (row 0: 0);
- acceleration at row i: |p_{i+1} - 2 p_i + p_{i-1}| / T^2, jerk at row i:
  |p_{i+1} - 3 p_i + 3 p_{i-1} - p_{i-2}| / T^3. The machine is at rest before the first
  and after the last set-point (positions held), so the start and the stop are measured too;
  the maxima also include the jerk of coming to rest after the last row;
- chord error of the step ending at row i: the largest distance from the true curve between
  the two set-points to the straight chord joining them (steps across a block junction use
  the pieces of both blocks; planning.chord_error); assigned to the step's end row, 0 for row 0;
- feed fluctuation of a step: |speed - planned feed| / planned feed, where the trajectory's
  ``feed_mm_s[i]`` is the feed the planner commanded for the step ending at row i
  (rows with no planned feed count 0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.planning.chord_error import ProgramCurves, chord_errors
from nurbsmotion.planning.rows import column_max, row_norms
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Program

@dataclass(eq=False)
class Measurements:
    """Per-row arrays (length N = number of set-points) and their summary figures."""

    chord_error_mm: NDArray[np.float64]
    speed_mm_s: NDArray[np.float64]
    accel_mm_s2: NDArray[np.float64]
    jerk_mm_s3: NDArray[np.float64]
    fluctuation: NDArray[np.float64]
    max_chord_error_mm: float
    min_chord_error_mm: float
    max_speed_mm_s: float
    max_accel_mm_s2: float
    max_jerk_mm_s3: float
    max_fluctuation: float
    start_error_mm: float
    end_error_mm: float
    axis_max_velocity_mm_s: tuple[float, ...]
    axis_max_accel_mm_s2: tuple[float, ...]
    cycles: int
    duration_s: float
    length_mm: float

    def summary(self) -> dict[str, float | int | list[float]]:
        """The scalar figures as a plain dict (for JSON output and tables)."""
        return {
            "cycles": self.cycles,
            "duration_s": self.duration_s,
            "length_mm": self.length_mm,
            "max_chord_error_mm": self.max_chord_error_mm,
            "min_chord_error_mm": self.min_chord_error_mm,
            "max_speed_mm_s": self.max_speed_mm_s,
            "max_accel_mm_s2": self.max_accel_mm_s2,
            "max_jerk_mm_s3": self.max_jerk_mm_s3,
            "max_fluctuation": self.max_fluctuation,
            "start_error_mm": self.start_error_mm,
            "end_error_mm": self.end_error_mm,
            "axis_max_velocity_mm_s": list(self.axis_max_velocity_mm_s),
            "axis_max_accel_mm_s2": list(self.axis_max_accel_mm_s2),
        }


def rest_padded_differences(position_mm: NDArray[np.float64], period_s: float) -> tuple[NDArray[np.float64], ...]:
    """Velocity, acceleration and jerk vectors by finite differences, at rest outside the run.

    Returns (v (N, dim): step ending at row i, row 0 zero; a (N, dim) centred on row i;
    j (N + 1, dim): a_i - a_{i-1} over T for i = 0..N, the last one coming to rest).
    """
    p = np.asarray(position_mm, dtype=np.float64)
    padded = np.concatenate([p[:1], p[:1], p, p[-1:], p[-1:]])
    first = np.diff(padded, axis=0)  # first[k] = padded[k+1] - padded[k]
    second = np.diff(first, axis=0)  # centred on padded[k+1]
    v = first[1:-2] / period_s  # rows 0..N-1: p_i - p_{i-1}
    a = second[1:-1] / period_s**2  # rows 0..N-1
    a_with_rest = second / period_s**2  # rows -1..N
    j = np.diff(a_with_rest, axis=0) / period_s  # rows 0..N
    return v, a, j


@dataclass(eq=False)
class RowFigures:
    """Measured figures of consecutive rows ``first_row``.. of a plan (MeasureStream.add)."""

    first_row: int
    rows: Trajectory
    chord_error_mm: NDArray[np.float64]
    speed_mm_s: NDArray[np.float64]
    accel_mm_s2: NDArray[np.float64]
    jerk_mm_s3: NDArray[np.float64]
    fluctuation: NDArray[np.float64]
    axis_velocity_mm_s: NDArray[np.float64]  # (n, dim) |p_i - p_i-1| / T
    axis_accel_mm_s2: NDArray[np.float64]  # (n, dim)

    def __len__(self) -> int:
        return len(self.rows)


def _rows(trajectory: Trajectory, sl: slice) -> Trajectory:
    return Trajectory(trajectory.algorithm, trajectory.period_s, trajectory.block[sl], trajectory.u[sl],
                      trajectory.position_mm[sl], trajectory.feed_mm_s[sl])


class MeasureStream:
    """measure() for a plan that arrives in chunks, in memory bounded by the chunk: ``add``
    each chunk in order, then ``finish``; both return the rows measured so far (a row is
    measured once the row after it is known: its acceleration is a central difference).
    ``measurements()`` then has the summary figures (its per-row arrays are empty unless
    ``keep_rows``). The machine is at rest before the first and after the last row."""

    def __init__(self, program: Program, keep_rows: bool = False) -> None:
        self.program = program
        self.keep_rows = keep_rows
        self.kept: list[RowFigures] = []
        self.pending: Trajectory | None = None  # received rows not yet measured
        self.history: NDArray[np.float64] | None = None  # the two positions before ``pending``
        self.previous: Trajectory | None = None  # the last measured row (chord error of the next step)
        self.rows = 0
        self.first: NDArray[np.float64] | None = None
        self.last: NDArray[np.float64] | None = None
        self.period_s = 0.0
        self.max = {"chord": 0.0, "speed": 0.0, "accel": 0.0, "jerk": 0.0, "fluctuation": 0.0}
        self.min_chord = np.inf
        self.length_mm = 0.0
        self.axis_v: NDArray[np.float64] | None = None
        self.axis_a: NDArray[np.float64] | None = None

    def add(self, chunk: Trajectory) -> RowFigures | None:
        if len(chunk) == 0:
            return None
        self.period_s = chunk.period_s
        if self.first is None:
            self.first = np.asarray(chunk.position_mm[0], float)
            self.history = np.repeat(self.first[None, :], 2, axis=0)
        rows = chunk if self.pending is None else Trajectory.concatenate([self.pending, chunk])
        self.pending = _rows(rows, slice(len(rows) - 1, None))
        return self._measure(rows, len(rows) - 1, np.zeros((0, rows.position_mm.shape[1])))

    def finish(self) -> RowFigures | None:
        """Measure the last row (the machine then stays at rest there)."""
        if self.pending is None:
            return None
        rows, self.pending = self.pending, None
        self.last = np.asarray(rows.position_mm[-1], float)
        return self._measure(rows, len(rows), np.repeat(rows.position_mm[-1:], 2, axis=0))

    def _measure(self, rows: Trajectory, n: int, after: NDArray[np.float64]) -> RowFigures | None:
        """Figures of the first ``n`` rows of ``rows``; ``after`` the positions following them."""
        period = rows.period_s
        p = np.asarray(rows.position_mm, float)
        ext = np.concatenate([self.history, p, after])  # p_-2, p_-1, p_0 .. p_n (.. p_n+1 at the end)
        v = np.diff(ext, axis=0)[1: n + 1] / period
        second = (ext[2:] - 2.0 * ext[1:-1] + ext[:-2]) / period**2  # a_-1 .. a_n
        a = second[1: n + 1]
        jerk = row_norms(np.diff(second, axis=0)) / period  # j_0 .. j_n
        extra_jerk = float(jerk[n]) if len(jerk) > n else 0.0  # coming to rest after the last row
        jerk = jerk[:n]
        self.history = ext[n: n + 2]
        if n == 0:
            return None
        part = _rows(rows, slice(0, n))
        speed = row_norms(v)
        feed = np.asarray(part.feed_mm_s, float)
        planned = feed > 1e-12
        fluctuation = np.where(planned, np.abs(speed - feed) / np.where(planned, feed, 1.0), 0.0)
        joined = part if self.previous is None else Trajectory.concatenate([self.previous, part])
        first, curves = self.curves_along(joined.block)
        chord = chord_errors(joined.block - first, joined.u, joined.position_mm, curves)[len(joined) - n:]
        if self.previous is None:
            fluctuation[0] = 0.0
        figures = RowFigures(self.rows, part, chord, speed, row_norms(a), jerk, fluctuation,
                             np.abs(v), np.abs(a))
        self._accumulate(figures, extra_jerk)
        self.previous = _rows(part, slice(n - 1, n))
        return figures

    def curves_along(self, blocks: NDArray[np.integer]) -> tuple[int, ProgramCurves]:
        """(first, the curves of the program's blocks first..last of ``blocks``): gathered per
        chunk, so the first chunk does not wait for the whole program's (0.64 s at 10^4 blocks),
        and ``program.blocks`` may grow as the plan is set up (PlannedPath.streamed)."""
        first, last = (int(blocks.min()), int(blocks.max())) if len(blocks) else (0, -1)
        window = replace(self.program, blocks=self.program.blocks[first:last + 1])
        return first, ProgramCurves.of(window)

    def _accumulate(self, f: RowFigures, extra_jerk: float) -> None:
        for key, values in (("chord", f.chord_error_mm), ("speed", f.speed_mm_s), ("accel", f.accel_mm_s2),
                            ("jerk", f.jerk_mm_s3), ("fluctuation", f.fluctuation)):
            self.max[key] = max(self.max[key], float(values.max(initial=0.0)))
        self.max["jerk"] = max(self.max["jerk"], extra_jerk)
        later = f.chord_error_mm[1:] if f.first_row == 0 else f.chord_error_mm
        self.min_chord = min(self.min_chord, float(later.min(initial=np.inf)))
        self.length_mm += float(f.speed_mm_s.sum() * self.period_s)
        v, a = column_max(f.axis_velocity_mm_s), column_max(f.axis_accel_mm_s2)
        self.axis_v = v if self.axis_v is None else np.maximum(self.axis_v, v)
        self.axis_a = a if self.axis_a is None else np.maximum(self.axis_a, a)
        self.rows += len(f)
        if self.keep_rows:
            self.kept.append(f)

    def measurements(self) -> Measurements:
        """The figures of every row measured (call after finish)."""
        def rows(name: str) -> NDArray[np.float64]:
            return np.concatenate([getattr(k, name) for k in self.kept]) if self.kept else np.zeros(0)

        start = self.program.blocks[0].start if self.program.blocks else self.program.start_position
        dim = len(self.first) if self.first is not None else 3
        return Measurements(
            chord_error_mm=rows("chord_error_mm"), speed_mm_s=rows("speed_mm_s"), accel_mm_s2=rows("accel_mm_s2"),
            jerk_mm_s3=rows("jerk_mm_s3"), fluctuation=rows("fluctuation"),
            max_chord_error_mm=self.max["chord"],
            min_chord_error_mm=float(self.min_chord) if self.rows > 1 else 0.0,
            max_speed_mm_s=self.max["speed"], max_accel_mm_s2=self.max["accel"], max_jerk_mm_s3=self.max["jerk"],
            max_fluctuation=self.max["fluctuation"],
            start_error_mm=float(np.linalg.norm(self.first - start)) if self.first is not None else float("nan"),
            end_error_mm=float(np.linalg.norm(self.last - self.program.end_position)) if self.last is not None else float("nan"),
            axis_max_velocity_mm_s=tuple(float(x) for x in (self.axis_v if self.axis_v is not None else np.zeros(dim))),
            axis_max_accel_mm_s2=tuple(float(x) for x in (self.axis_a if self.axis_a is not None else np.zeros(dim))),
            cycles=max(self.rows - 1, 0),
            duration_s=max(self.rows - 1, 0) * self.period_s,
            length_mm=self.length_mm,
        )


def measure(trajectory: Trajectory, program: Program) -> Measurements:
    """All measured figures of a trajectory (see the module docstring for the definitions)."""
    stream = MeasureStream(program, keep_rows=True)
    stream.add(trajectory)
    stream.finish()
    return stream.measurements()
