"""A completed job's last events (M5 M9 before M30) are done and recorded, in order, even when
the events thread is inside a slow SDO transfer as the job ends (the vcan spindle flake)."""

from __future__ import annotations

import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import pytest

from nurbsmotion.program.model import CoolantMode, EventKind, ProgramEvent, SourceRef, SpindleDirection
from nurbsmotion.service import job_events
from nurbsmotion.service.devices import MachineDevices
from nurbsmotion.service.job_events import JobEvents, RowEvent
from tests.helpers import wait_for


class SlowBus:
    """A spindle and a coolant output whose first spindle command blocks until released (an SDO
    write waiting behind the monitor's reads on a slow bus)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.in_transfer = threading.Event()
        self.done: list[str] = []
        self.spindle = SimpleNamespace(command_rpm=self.command_rpm)
        self.io = SimpleNamespace(set_coolant=self.set_coolant)

    def command_rpm(self, rpm: float) -> None:
        self.in_transfer.set()
        self.release.wait(30)
        self.done.append(f"rpm {rpm:g}")

    def set_coolant(self, mode: CoolantMode) -> dict[str, bool]:
        self.done.append(f"coolant {mode.value}")
        return {"coolant_flood": mode is CoolantMode.FLOOD}


def ending_events() -> list[RowEvent]:
    """M5 then M9 after the last move (row 10 of a 10-row job)."""
    where = SourceRef("end.nc", 8)
    return [RowEvent(10, ProgramEvent(EventKind.SPINDLE, 1, where, "M5", spindle=SpindleDirection.OFF)),
            RowEvent(10, ProgramEvent(EventKind.COOLANT, 1, SourceRef("end.nc", 9), "M9", coolant=CoolantMode.OFF))]


def events_runner(bus: SlowBus, folder: Path) -> JobEvents:
    status = SimpleNamespace(job_index=9, phase="running", pause=None)
    return JobEvents(ending_events(), (), lambda: True, cast(MachineDevices, bus), folder,
                     lambda: status, lambda: None, lambda reason: None)


def finish_in_thread(runner: JobEvents, drain: bool) -> threading.Thread:
    thread = threading.Thread(target=runner.finish, kwargs={"drain": drain})
    thread.start()
    return thread


def test_the_end_of_a_completed_job_waits_for_a_slow_transfer_and_then_does_m9(tmp_path: Path) -> None:
    bus = SlowBus()
    runner = events_runner(bus, tmp_path)
    runner.start()
    wait_for(bus.in_transfer.is_set, 5, "the events thread to start M5's transfer")
    ender = finish_in_thread(runner, drain=True)
    ender.join(2.3)  # longer than the 2 s the job's end used to wait (M9 was then skipped)
    assert ender.is_alive(), "the job's end must wait for the transfer in progress"
    bus.release.set()
    ender.join(10)
    assert bus.done == ["rpm 0", "coolant off"]
    assert [e["code"] for e in runner.done] == ["M5", "M9"]
    assert "M9" in (tmp_path / "events.log").read_text()


def test_a_job_that_did_not_complete_is_not_drained(tmp_path: Path, monkeypatch: Any) -> None:
    monkeypatch.setattr(job_events, "STOP_WAIT_S", 0.05)
    bus = SlowBus()
    runner = events_runner(bus, tmp_path)
    runner.start()
    wait_for(bus.in_transfer.is_set, 5, "the events thread to start M5's transfer")
    ender = finish_in_thread(runner, drain=False)
    ender.join(5)
    assert not ender.is_alive()
    bus.release.set()
    wait_for(lambda: not runner._thread.is_alive(), 5, "the events thread to end")
    assert bus.done == ["rpm 0"]  # the transfer in progress ends; M9 is not started


@pytest.mark.parametrize("drain", [True, False])
def test_a_transfer_that_never_ends_is_given_up_with_one_line(tmp_path: Path, monkeypatch: Any, caplog: Any,
                                                               drain: bool) -> None:
    monkeypatch.setattr(job_events, "DRAIN_WAIT_S", 0.1)
    monkeypatch.setattr(job_events, "STOP_WAIT_S", 0.1)
    bus = SlowBus()
    runner = events_runner(bus, tmp_path)
    runner.start()
    wait_for(bus.in_transfer.is_set, 5, "the events thread to start M5's transfer")
    runner.finish(drain=drain)
    assert "job_events_late" in caplog.text
    bus.release.set()
    wait_for(lambda: not runner._thread.is_alive(), 5, "the events thread to end")
    assert bus.done == ["rpm 0"]  # nothing after the given-up transfer
    if drain:
        assert "job_event_not_done" in caplog.text and "M9" in caplog.text
