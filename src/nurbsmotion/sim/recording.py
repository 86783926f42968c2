"""Recording of every set-point a simulated drive applied, for tests that prove no set-point
was lost or repeated. One row per applied set-point: the drive's SYNC index (SYNCs received
since it last entered NMT OPERATIONAL; the first is 1), the mode, the set-point and the
actual position after that SYNC, and the SYNC frame's counter byte (-1 if the frame had none).

Rows are kept as 64-bit integers in one flat ``array`` (40 bytes per set-point: 144 MB per
drive and hour at 1 kHz); a disabled recorder keeps nothing.
"""

from __future__ import annotations

import array
import csv
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
_WIDTH = len(CSV_HEADER)


class SetpointRecorder:
    """Append-only record of applied set-points (one ``array.extend`` per set-point)."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self._values = array.array("q")

    def append(self, sync_index: int, mode: int, setpoint: int, actual: int, sync_counter: int) -> None:
        if self.enabled:
            self._values.extend((sync_index, mode, setpoint, actual, sync_counter))

    def __len__(self) -> int:
        return len(self._values) // _WIDTH

    def as_array(self) -> np.ndarray:
        """(n, 5) int64 copy with the columns of ``CSV_HEADER``."""
        values = self._values[: len(self) * _WIDTH]  # a row being appended is left out
        return np.frombuffer(values, dtype=np.int64).reshape(-1, _WIDTH).copy()

    def records(self) -> list[SetpointRecord]:
        return [SetpointRecord(*(int(v) for v in row)) for row in self.as_array()]

    def clear(self) -> None:
        self._values = array.array("q")

    def write_csv(self, path: str | Path) -> Path:
        """Write the records as CSV with a header line; returns the path."""
        path = Path(path)
        with path.open("w", newline="", encoding="utf-8") as out:
            writer = csv.writer(out)
            writer.writerow(CSV_HEADER)
            writer.writerows(self.as_array().tolist())
        return path


def read_csv(path: str | Path) -> list[SetpointRecord]:
    """Read a file written by :meth:`SetpointRecorder.write_csv`."""
    with Path(path).open(newline="", encoding="utf-8") as src:
        reader = csv.reader(src)
        header = next(reader, None)
        if header is None or tuple(header) != CSV_HEADER:
            raise ValueError(f"{path}: not a set-point recording (header {header})")
        return [SetpointRecord(*(int(v) for v in row)) for row in reader]
