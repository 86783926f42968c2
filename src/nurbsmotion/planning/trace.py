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
from nurbsmotion.planning.measure import Measurements
from nurbsmotion.planning.trajectory import Trajectory

TRACE_COLUMNS = ("t", "block", "u", "x", "y", "z", "feed", "chord_error", "accel", "jerk")
TRACE_UNITS = {"t": "s", "block": "", "u": "", "x": "mm", "y": "mm", "z": "mm", "feed": "mm/s",
               "chord_error": "mm", "accel": "mm/s^2", "jerk": "mm/s^3"}
_FORMATS = ("%.6f", "%d", "%.15g", "%.9f", "%.9f", "%.9f", "%.6f", "%.4e", "%.6g", "%.6g")


def trace_table(trajectory: Trajectory, measurements: Measurements) -> NDArray[np.float64]:
    """The trace as an (N, 10) array in TRACE_COLUMNS order."""
    p = trajectory.position_mm
    if p.shape[1] != 3:
        raise ValueError(f"trace needs XYZ set-points, got {p.shape[1]} coordinates")
    return np.column_stack([trajectory.t_s, trajectory.block, trajectory.u, p, trajectory.feed_mm_s,
                            measurements.chord_error_mm, measurements.accel_mm_s2, measurements.jerk_mm_s3])


def write_trace(path: str | Path, trajectory: Trajectory, measurements: Measurements) -> None:
    """Write the trace CSV (header line TRACE_COLUMNS, then one line per cycle)."""
    table = trace_table(trajectory, measurements)
    try:
        with open(path, "w", encoding="ascii", newline="") as out:
            np.savetxt(out, table, fmt=list(_FORMATS), delimiter=",", header=",".join(TRACE_COLUMNS), comments="")
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
