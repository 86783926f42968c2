"""What a simulated drive recorded, for tests that prove no set-point was lost, repeated or late.

Two tables, each row a few 64-bit integers in one flat ``array`` (a disabled recorder keeps
nothing):

- ``SetpointRecord``: one row per set-point the drive applied (a fresh one from the master):
  the drive's SYNC index (SYNCs received since it last entered NMT OPERATIONAL; the first is
  1), the mode, the set-point, the actual position after that SYNC, the SYNC frame's counter
  byte (-1 if the frame had none) and the SYNC's time (ns, the drive's clock). 48 bytes per
  set-point: 173 MB per drive and hour at 1 kHz.
- ``SyncRecord``: one row per SYNC in NMT OPERATIONAL: its time, the interval since the
  previous SYNC, the drive cycles that ran without a SYNC before it, where that cycle's
  set-point came from (``SetpointSource``), the demand, the actual position and the
  following error. This is where a stop-and-go shows (see ``stats.stream_report``).
"""

from __future__ import annotations

import array
import csv
import enum
import io
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np

from nurbsmotion.chunked_file import take_text, write_file
from nurbsmotion.steps import Steps, drained

# rows formatted per step of csv_steps: ~50 us on the 2-core test machine (6 columns)
CSV_ROWS_PER_STEP = 50


class SetpointSource(enum.IntEnum):
    """Where the set-point of a drive cycle came from."""

    INACTIVE = 0  # no set-point in use (not OPERATION ENABLED, IP without bit 4, other mode)
    FRESH = 1  # received from the master since the previous SYNC
    HELD = 2  # none received: the last one kept
    EXTRAPOLATED = 3  # none received: the last step continued


@dataclass(frozen=True)
class SetpointRecord:
    sync_index: int
    mode: int
    setpoint_counts: int
    position_actual_counts: int
    sync_counter: int
    sync_time_ns: int


@dataclass(frozen=True)
class SyncRecord:
    sync_index: int
    sync_time_ns: int
    interval_ns: int  # -1 for the first SYNC after entering OPERATIONAL
    missed_ticks: int
    source: int  # SetpointSource
    demand_counts: int
    position_actual_counts: int
    following_error_counts: int
    sync_counter: int


R = TypeVar("R", SetpointRecord, SyncRecord)


class _Recorder(Generic[R]):
    """Append-only table of ``record_type`` rows (one ``array.extend`` per row)."""

    record_type: type[R]

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self._width = len(fields(self.record_type))
        self._values = array.array("q")

    @classmethod
    def header(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls.record_type))

    def append(self, *values: int) -> None:
        if self.enabled:
            self._values.extend(values)

    def __len__(self) -> int:
        return len(self._values) // self._width

    def as_array(self) -> np.ndarray:
        """(n, columns) int64 copy with the columns of ``header()``."""
        values = self._values[: len(self) * self._width]  # a row being appended is left out
        return np.frombuffer(values, dtype=np.int64).reshape(-1, self._width).copy()

    def records(self) -> list[R]:
        return [self.record_type(*(int(v) for v in row)) for row in self.as_array()]

    def clear(self) -> None:
        self._values = array.array("q")

    def write_csv(self, path: str | Path) -> Path:
        """Write the rows as CSV with a header line; returns the path."""
        return write_file(path, drained(self.csv_chunks(), lambda _: None))

    def csv_chunks(self, rows_per_step: int = CSV_ROWS_PER_STEP) -> Steps[list[bytes]]:
        """The CSV text of :meth:`write_csv` (header line first), encoded, one chunk of
        ``rows_per_step`` rows a step (steps.Steps): each step's formatting is one C call
        that holds the interpreter lock throughout (a whole job's rows took ~30 ms per
        drive), so the daemon runs them in the cycle thread's slack (fieldbus.cycle_slack)
        and writes the chunks in its own thread (chunked_file). The rows recorded before
        the first step."""
        recorded, width, end = self._values, self._width, len(self) * self._width  # a clear() meanwhile: these rows
        text = io.StringIO()
        writer = csv.writer(text)
        writer.writerow(self.header())
        chunks = [take_text(text)]
        for start in range(0, end, rows_per_step * width):
            yield None
            values = recorded[start: min(start + rows_per_step * width, end)]
            writer.writerows(np.frombuffer(values, dtype=np.int64).reshape(-1, width).tolist())
            chunks.append(take_text(text))
        return chunks


class SetpointRecorder(_Recorder[SetpointRecord]):
    """Applied set-points: ``append(sync_index, mode, setpoint, actual, sync_counter, sync_time_ns)``."""

    record_type = SetpointRecord


class SyncRecorder(_Recorder[SyncRecord]):
    """Every SYNC: ``append(*SyncRecord fields)``."""

    record_type = SyncRecord


CSV_HEADER = SetpointRecorder.header()
SYNC_CSV_HEADER = SyncRecorder.header()


def _read(path: str | Path, record_type: type[R]) -> list[R]:
    header_wanted = tuple(f.name for f in fields(record_type))
    with Path(path).open(newline="", encoding="utf-8") as src:
        reader = csv.reader(src)
        header = next(reader, None)
        if header is None or tuple(header) != header_wanted:
            raise ValueError(f"{path}: not a {record_type.__name__} recording (header {header})")
        return [record_type(*(int(v) for v in row)) for row in reader]


def read_csv(path: str | Path) -> list[SetpointRecord]:
    """Read a file written by :meth:`SetpointRecorder.write_csv`."""
    return _read(path, SetpointRecord)


def read_sync_csv(path: str | Path) -> list[SyncRecord]:
    """Read a file written by :meth:`SyncRecorder.write_csv`."""
    return _read(path, SyncRecord)
