"""Set-point recording: rows, CSV, disabled recorder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.sim import SetpointRecord, SetpointRecorder, read_csv


def test_rows_in_order_as_records_and_array(tmp_path: Path) -> None:
    recorder = SetpointRecorder()
    recorder.append(1, 8, -5, -4, -1)
    recorder.append(2, 7, 2**40, 2**40 - 1, 255)
    assert recorder.records() == [SetpointRecord(1, 8, -5, -4, -1), SetpointRecord(2, 7, 2**40, 2**40 - 1, 255)]
    assert np.array_equal(recorder.as_array()[:, 0], [1, 2]) and recorder.as_array().dtype == np.int64
    assert read_csv(recorder.write_csv(tmp_path / "r.csv")) == recorder.records()


def test_disabled_recorder_keeps_nothing_and_writes_an_empty_table(tmp_path: Path) -> None:
    recorder = SetpointRecorder(enabled=False)
    recorder.append(1, 8, 0, 0, -1)
    assert len(recorder) == 0 and recorder.as_array().shape == (0, 5)
    assert read_csv(recorder.write_csv(tmp_path / "r.csv")) == []


def test_clear() -> None:
    recorder = SetpointRecorder()
    recorder.append(1, 8, 0, 0, -1)
    recorder.clear()
    assert len(recorder) == 0


def test_read_csv_refuses_another_file(tmp_path: Path) -> None:
    path = tmp_path / "other.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="not a set-point recording"):
        read_csv(path)
