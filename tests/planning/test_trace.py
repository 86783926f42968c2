"""planning.trace: the CSV header, units and one row per cycle."""

from __future__ import annotations

import numpy as np

from nurbsmotion.geometry.primitives import line_curve
from nurbsmotion.planning.measure import measure
from nurbsmotion.planning.trace import TRACE_COLUMNS, read_trace, write_trace
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import Block, BlockKind, Program, SourceRef


def test_trace_header_rows_and_values(tmp_path):
    line = line_curve((0, 0, 0), (3, 4, 0))
    prog = Program("t", (Block(BlockKind.LINE, line, 5.0, SourceRef("t", 1)),), line.start_point)
    u = np.linspace(0, 1, 6)
    traj = Trajectory("test", 0.004, np.zeros(6, np.int32), u, line.points(u), np.r_[0.0, np.full(5, 250.0)])
    m = measure(traj, prog)
    path = tmp_path / "trace.csv"
    write_trace(path, traj, m)
    lines = path.read_text().splitlines()
    assert lines[0] == "t,block,u,x,y,z,feed,chord_error,accel,jerk"
    assert len(lines) == 1 + len(traj)
    data = read_trace(path)
    assert tuple(data) == TRACE_COLUMNS
    np.testing.assert_allclose(data["t"], np.arange(6) * 0.004)  # seconds
    np.testing.assert_allclose([data["x"][-1], data["y"][-1]], [3.0, 4.0])  # mm
    np.testing.assert_allclose(data["feed"], traj.feed_mm_s)  # mm/s
    np.testing.assert_allclose(data["accel"], m.accel_mm_s2, rtol=1e-5)  # mm/s^2
    np.testing.assert_allclose(data["jerk"], m.jerk_mm_s3, rtol=1e-5)  # mm/s^3


def test_rows_are_formatted_as_savetxt_writes_them():
    """The trace's own formatting (one %-format of a chunk's values) against np.savetxt with
    the same formats, the former writer and the oracle: rounding halves, -0, tiny and huge
    values, exact integers."""
    import io

    from nurbsmotion.planning.trace import _FORMATS, formatted_rows

    rng = np.random.default_rng(3)
    table = rng.normal(0.0, 1.0, (500, len(TRACE_COLUMNS))) * 10.0 ** rng.integers(-12, 9, (500, len(TRACE_COLUMNS)))
    table[:, 1] = rng.integers(0, 10**6, 500)  # block numbers
    table[:5] = [[0.0005, 0, 0.125, 1.0000000005, -0.0, 2.5e-10, 0.0000005, 1.23455e-7, 0.5, 1e20]] * 5
    expected = io.StringIO()
    np.savetxt(expected, table, fmt=list(_FORMATS), delimiter=",")
    assert formatted_rows(table) == expected.getvalue()
    assert formatted_rows(table[:0]) == ""
