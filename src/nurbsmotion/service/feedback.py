"""What the drives reported during a job: every TPDO1 the master received (statusword 0x6041,
position actual 0x6064), written to the job's ``feedback.csv`` while the job runs.

The master hands each TPDO1 to :meth:`FeedbackLog.add` on canopen's receive thread
(``Master.record_feedback``); ``add`` only appends to a deque. About once a second and at
the end, the job's watcher thread has the lines formatted in the cycle thread's slack
(:meth:`FeedbackLog.line_steps`, fieldbus.cycle_slack) and writes them (:meth:`FeedbackLog.write`),
so memory stays small however long the job is, and the formatting never holds the
interpreter lock when the cycle thread wakes. One row per TPDO (not one per cycle): when the receive thread lags,
two answers of one axis may arrive within one master cycle, and both are kept.

Columns: ``job_cycle`` (master cycle at arrival minus the job's start cycle: 0 is the cycle
that sent the first set-point, negative rows were received before it), ``axis``, ``node``,
``statusword``, ``position_counts``, ``position_mm`` (AxisMap.to_mm), ``time_s`` (receive
time since the first row).
"""

from __future__ import annotations

import collections
from pathlib import Path
from typing import BinaryIO

from nurbsmotion.axes import AxisMap
from nurbsmotion.chunked_file import write_all
from nurbsmotion.fieldbus.cycle_slack import CycleSlack, run_steps
from nurbsmotion.steps import Steps

HEADER = "job_cycle,axis,node,statusword,position_counts,position_mm,time_s\n"
ROWS_PER_STEP = 50  # lines formatted per step of line_steps: ~75 us on the 2-core test machine


class FeedbackLog:
    """One job's feedback.csv (see module docstring)."""

    def __init__(self, path: Path, axis_map: AxisMap) -> None:
        self.path = path
        self.rows = 0
        self._prefix = [f"{name},{node}," for name, node in zip(axis_map.names, axis_map.node_ids)]
        self._offset = [int(o) for o in axis_map.offset_counts]
        self._mm_per_count = [float(s) / float(c) for s, c in zip(axis_map.sign, axis_map.counts_per_mm)]
        self._samples: collections.deque[tuple[int, int, int, int, float]] = collections.deque()
        self._t0: float | None = None
        self._out: BinaryIO | None = open(path, "wb", buffering=0)
        write_all(self._out, [HEADER.encode("ascii")])

    def add(self, cycle: int, axis: int, statusword: int, position_counts: int, timestamp: float) -> None:
        """The master's FeedbackSink: called on the receive thread, so only an append."""
        self._samples.append((cycle, axis, statusword, position_counts, timestamp))

    def flush(self, start_cycle: int, slack: CycleSlack | None = None) -> None:
        """Write the samples received so far; ``start_cycle``: the master cycle of job cycle 0.
        The lines are formatted in the cycle thread's ``slack`` when given (fieldbus.cycle_slack),
        else here; they are written here."""
        self.write(run_steps(self.line_steps(start_cycle), slack, bulk=True))

    def line_steps(self, start_cycle: int, rows_per_step: int = ROWS_PER_STEP) -> Steps[list[bytes]]:
        """The lines of the samples received so far, encoded, one chunk of ``rows_per_step``
        a step (steps.Steps): the daemon formats them in the cycle thread's slack
        (fieldbus.cycle_slack), a second of three axes being ~5 ms of Python, and writes them
        in the job's thread (:meth:`write`)."""
        samples = self._samples
        if self._out is None or not samples:
            return []
        if self._t0 is None:
            self._t0 = samples[0][4]
        t0, prefix, offset, scale = self._t0, self._prefix, self._offset, self._mm_per_count
        chunks = []
        left = len(samples)  # the receive thread appends meanwhile: those wait for the next flush
        while left:
            yield None
            lines = []
            for _ in range(min(rows_per_step, left)):  # %-formatting with a per-axis prefix: half an f-string's time
                cycle, i, sw, pos, stamp = samples.popleft()
                lines.append("%d,%s%d,%d,%.6f,%.6f\n" % (cycle - start_cycle, prefix[i], sw, pos,
                                                           (pos - offset[i]) * scale[i], stamp - t0))
            left -= len(lines)
            self.rows += len(lines)
            chunks.append("".join(lines).encode("ascii"))
        return chunks

    def write(self, chunks: list[bytes]) -> None:
        """Append ``chunks`` (:meth:`line_steps`) to the file (chunked_file: a system call a chunk)."""
        if self._out is not None:
            write_all(self._out, chunks)

    def close(self, start_cycle: int, slack: CycleSlack | None = None) -> None:
        self.flush(start_cycle, slack)
        if self._out is not None:
            self._out.close()
            self._out = None
