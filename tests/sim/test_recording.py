"""Set-point recording: rows, CSV, disabled recorder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.sim import SetpointRecord, SetpointRecorder, read_csv
from nurbsmotion.sim.recording import SetpointSource, SyncRecord, SyncRecorder, read_sync_csv


def test_rows_in_order_as_records_and_array(tmp_path: Path) -> None:
    recorder = SetpointRecorder()
    recorder.append(1, 8, -5, -4, -1, 1_000_000)
    recorder.append(2, 7, 2**40, 2**40 - 1, 255, 2_000_000)
    assert recorder.records() == [SetpointRecord(1, 8, -5, -4, -1, 1_000_000),
                                  SetpointRecord(2, 7, 2**40, 2**40 - 1, 255, 2_000_000)]
    assert np.array_equal(recorder.as_array()[:, 0], [1, 2]) and recorder.as_array().dtype == np.int64
    assert read_csv(recorder.write_csv(tmp_path / "r.csv")) == recorder.records()


def test_disabled_recorder_keeps_nothing_and_writes_an_empty_table(tmp_path: Path) -> None:
    recorder = SetpointRecorder(enabled=False)
    recorder.append(1, 8, 0, 0, -1, 0)
    assert len(recorder) == 0 and recorder.as_array().shape == (0, 6)
    assert read_csv(recorder.write_csv(tmp_path / "r.csv")) == []


def test_clear() -> None:
    recorder = SetpointRecorder()
    recorder.append(1, 8, 0, 0, -1, 0)
    recorder.clear()
    assert len(recorder) == 0


def test_read_csv_refuses_another_file(tmp_path: Path) -> None:
    path = tmp_path / "other.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="not a SetpointRecord recording"):
        read_csv(path)


def test_sync_timeline_rows_round_trip(tmp_path: Path) -> None:
    timeline = SyncRecorder()
    timeline.append(1, 1_000_000, -1, 0, int(SetpointSource.INACTIVE), 0, 0, 0, -1)
    timeline.append(2, 3_000_000, 2_000_000, 1, int(SetpointSource.FRESH), 10, 5, 5, 2)
    assert timeline.records()[1] == SyncRecord(2, 3_000_000, 2_000_000, 1, 1, 10, 5, 5, 2)
    assert read_sync_csv(timeline.write_csv(tmp_path / "t.csv")) == timeline.records()
    with pytest.raises(ValueError, match="not a SetpointRecord recording"):
        read_csv(tmp_path / "t.csv")


def test_csv_in_chunks_a_step_holds_the_rows_recorded_before_its_first_step(tmp_path: Path) -> None:
    recorder = SetpointRecorder()
    for i in range(7):
        recorder.append(i, 8, i * 10, i * 10 - 1, i % 256, i * 1_000_000)
    expected = recorder.records()
    steps = recorder.csv_chunks(rows_per_step=3)
    next(steps)  # the rows up to here are formatted: one appended later is not
    recorder.append(7, 8, 70, 69, 7, 7_000_000)
    yielded = 1
    try:
        while True:
            next(steps)
            yielded += 1
    except StopIteration as end:
        chunks = end.value
    assert yielded == 3 and [c.count(b"\n") for c in chunks] == [1, 3, 3, 1]  # the header, then 3 rows a step
    (tmp_path / "r.csv").write_bytes(b"".join(chunks))
    assert read_csv(tmp_path / "r.csv") == expected
