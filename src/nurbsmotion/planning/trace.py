"""Trace CSV: one row per interpolation cycle, from t = 0 at the start point to the end point.

Columns and units: ``t`` s, ``block`` (program block index), ``u`` (curve parameter in that
block), ``x,y,z`` mm, ``feed`` mm/s (the feed the planner commanded for the step ending at
that row), ``chord_error`` mm, ``accel`` mm/s^2, ``jerk`` mm/s^3 (the last three measured
by planning.measure from the set-points and the true curve).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.errors import InputError
from nurbsmotion.planning.measure import Measurements, RowFigures
from nurbsmotion.planning.trajectory import Trajectory

TRACE_COLUMNS = ("t", "block", "u", "x", "y", "z", "feed", "chord_error", "accel", "jerk")
TRACE_UNITS = {"t": "s", "block": "", "u": "", "x": "mm", "y": "mm", "z": "mm", "feed": "mm/s",
               "chord_error": "mm", "accel": "mm/s^2", "jerk": "mm/s^3"}
_FORMATS = ("%.6f", "%d", "%.15g", "%.9f", "%.9f", "%.9f", "%.6f", "%.4e", "%.6g", "%.6g")
_ROW = ",".join(_FORMATS) + "\n"
FORMAT_ROWS = 20000  # rows formatted per string (write_trace): memory ~ 2.5 MB of text


def formatted_rows(table: NDArray[np.float64]) -> str:
    """The CSV lines of ``table`` (rows of TRACE_COLUMNS), character for character what
    ``np.savetxt(fmt=_FORMATS, delimiter=",")`` writes, in one %-formatting of all its
    values (Python floats, not a numpy scalar and a format call per row): about 30 % faster."""
    return (_ROW * len(table)) % tuple(table.ravel().tolist())


def trace_table(trajectory: Trajectory, measurements: Measurements) -> NDArray[np.float64]:
    """The trace as an (N, 10) array in TRACE_COLUMNS order."""
    p = trajectory.position_mm
    if p.shape[1] != 3:
        raise ValueError(f"trace needs XYZ set-points, got {p.shape[1]} coordinates")
    return np.column_stack([trajectory.t_s, trajectory.block, trajectory.u, p, trajectory.feed_mm_s,
                            measurements.chord_error_mm, measurements.accel_mm_s2, measurements.jerk_mm_s3])


class TraceWriter:
    """The trace CSV written as the plan is measured, in chunks (MeasureStream's RowFigures):
    memory bounded by a chunk. Written to ``PATH.part`` and renamed to PATH by ``close()``;
    ``discard()`` removes it (a plan that fails leaves no trace behind)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.part = self.path.with_name(self.path.name + ".part")
        try:
            self.out = open(self.part, "w", encoding="ascii", newline="")
            self.out.write(",".join(TRACE_COLUMNS) + "\n")
        except OSError as err:
            raise InputError(str(path), f"cannot write trace: {err.strerror or err}") from None

    def write(self, figures: RowFigures) -> None:
        rows = figures.rows
        t = (figures.first_row + np.arange(len(rows))) * rows.period_s
        table = np.column_stack([t, rows.block, rows.u, rows.position_mm, rows.feed_mm_s, figures.chord_error_mm,
                                 figures.accel_mm_s2, figures.jerk_mm_s3])
        try:
            self.out.write(formatted_rows(table))
        except OSError as err:
            self.discard()
            raise InputError(str(self.path), f"cannot write trace: {err.strerror or err}") from None

    def close(self) -> None:
        try:
            self.out.close()
            self.part.replace(self.path)
        except OSError as err:
            self.discard()
            raise InputError(str(self.path), f"cannot write trace: {err.strerror or err}") from None

    def discard(self) -> None:
        self.out.close()
        self.part.unlink(missing_ok=True)


def write_trace(path: str | Path, trajectory: Trajectory, measurements: Measurements) -> None:
    """Write the trace CSV (header line TRACE_COLUMNS, then one line per cycle)."""
    table = trace_table(trajectory, measurements)
    try:
        with open(path, "w", encoding="ascii", newline="") as out:
            out.write(",".join(TRACE_COLUMNS) + "\n")
            for first in range(0, len(table), FORMAT_ROWS):
                out.write(formatted_rows(table[first:first + FORMAT_ROWS]))
    except OSError as err:
        raise InputError(str(path), f"cannot write trace: {err.strerror or err}") from None


def read_trace(path: str | Path) -> dict[str, NDArray[np.float64]]:
    """Read a trace CSV back: column name -> array (checks the header)."""
    with open(path, encoding="ascii") as src:
        header = src.readline().strip().split(",")
    if tuple(header) != TRACE_COLUMNS:
        raise InputError(f"{path}:1", f"not a nurbsmotion trace: header {','.join(header)!r}")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {name: data[:, i] for i, name in enumerate(TRACE_COLUMNS)}
