"""Recording of every set-point a simulated drive applied, for tests that prove no set-point
was lost or repeated. One row per applied set-point: the drive's SYNC index (SYNCs received
since it last entered NMT OPERATIONAL; the first is 1), the mode, the set-point and the
actual position after that SYNC, and the SYNC frame's counter byte (-1 if the frame had none).
"""

from __future__ import annotations

import csv
import threading
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class SetpointRecord:
    sync_index: int
    mode: int
    setpoint_counts: int
    position_actual_counts: int
    sync_counter: int


CSV_HEADER = tuple(f.name for f in fields(SetpointRecord))


class SetpointRecorder:
    """Append-only, thread-safe list of applied set-points (appending is a tuple append)."""

    def __init__(self) -> None:
        self._rows: list[tuple[int, int, int, int, int]] = []
        self._lock = threading.Lock()

    def append(self, sync_index: int, mode: int, setpoint: int, actual: int, sync_counter: int) -> None:
        self._rows.append((sync_index, mode, setpoint, actual, sync_counter))

    def __len__(self) -> int:
        return len(self._rows)

    def records(self) -> list[SetpointRecord]:
        with self._lock:
            rows = list(self._rows)
        return [SetpointRecord(*row) for row in rows]

    def as_array(self) -> np.ndarray:
        """(n, 5) int64 array with the columns of ``CSV_HEADER``."""
        rows = list(self._rows)
        return np.array(rows, dtype=np.int64).reshape(len(rows), len(CSV_HEADER))

    def clear(self) -> None:
        with self._lock:
            self._rows.clear()

    def write_csv(self, path: str | Path) -> Path:
        """Write the records as CSV with a header line; returns the path."""
        path = Path(path)
        rows = list(self._rows)
        with path.open("w", newline="", encoding="utf-8") as out:
            writer = csv.writer(out)
            writer.writerow(CSV_HEADER)
            writer.writerows(rows)
        return path


def read_csv(path: str | Path) -> list[SetpointRecord]:
    """Read a file written by :meth:`SetpointRecorder.write_csv`."""
    with Path(path).open(newline="", encoding="utf-8") as src:
        reader = csv.reader(src)
        header = next(reader)
        if tuple(header) != CSV_HEADER:
            raise ValueError(f"{path}: not a set-point recording (header {header})")
        return [SetpointRecord(*(int(v) for v in row)) for row in reader]
