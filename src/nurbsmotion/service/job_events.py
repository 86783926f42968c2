"""A job's spindle, coolant and digital output events, done at their set-point rows while the job runs.

Each program event (M3/M4/M5/S, M7/M8/M9) gets the row of the block it comes before (the
first row of that block, as service.planner.pause_rows). M3/M4 and S while the spindle turns
are exact stops (program.model ProgramEvent.waits_for_spindle) and become extra pause rows:
the master holds there at rest, this runner commands the spindle, waits for 'at speed'
within ``at_speed_timeout_s`` and resumes the job (unless M0/M1/M6 holds at the same row);
a timeout stops the job with one line. The others (M5, coolant) are done when playback
reaches their row (polled every ``POLL_S``: they need no cycle accuracy). Each event done is
one log line and one line of the job's ``events.log``.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from nurbsmotion.log import kv
from nurbsmotion.program import EventKind, ProgramEvent, SpindleDirection
from nurbsmotion.service.devices import MachineDevices
from nurbsmotion.service.planner import JobPause, PlannedJob
from nurbsmotion.service.records import now_iso

log = logging.getLogger(__name__)

POLL_S = 0.01
EVENTS_FILE = "events.log"


@dataclass(frozen=True)
class RowEvent:
    row: int  # first row of the block the event comes before (len(rows): after the last move)
    event: ProgramEvent

    @property
    def waits(self) -> bool:
        return self.event.waits_for_spindle


def event_rows(plan: PlannedJob) -> tuple[RowEvent, ...]:
    """Spindle and coolant events of the plan's program with their rows, in program order."""
    program = plan.program
    if program is None:
        return ()
    kinds = (EventKind.SPINDLE, EventKind.COOLANT, EventKind.OUTPUT)
    return tuple(RowEvent(int(np.searchsorted(plan.trajectory.block, e.before_block, side="left")), e)
                 for e in program.events if e.kind in kinds)


def signed_rpm(event: ProgramEvent) -> float:
    """+rpm for M3 (cw), -rpm for M4 (ccw), 0 for M5."""
    rpm = event.spindle_rpm or 0.0
    return {SpindleDirection.CW: rpm, SpindleDirection.CCW: -rpm}.get(event.spindle, 0.0)  # type: ignore[arg-type]


def with_spindle_waits(plan: PlannedJob) -> tuple[PlannedJob, frozenset[int]]:
    """The plan with a pause row at every spindle start/change inside the job (merged with the
    program's own pauses, one per row, sorted; the master's Playback keeps 0 <= row < last),
    and the rows added."""
    last = len(plan.counts) - 1
    rows = {p.row: p for p in plan.pauses}
    added = set()
    for e in event_rows(plan):
        if e.waits and 0 <= e.row < last and e.row not in rows:
            rows[e.row] = JobPause(e.row, f"{e.event.code} at {e.event.source}: waiting for the spindle at speed")
            added.add(e.row)
    return replace(plan, pauses=tuple(rows[r] for r in sorted(rows))), frozenset(added)


class JobEvents:
    """Runs one job's events on a thread; ``status()`` gives the master status (phase,
    job_index, pause), ``resume()`` continues the held job, ``stop(reason)`` ends it."""

    def __init__(self, plan: PlannedJob, wait_rows: frozenset[int], devices: MachineDevices, folder: Path,
                 status: Callable[[], Any], resume: Callable[[], None], stop: Callable[[str], None]) -> None:
        """``plan`` and ``wait_rows`` as with_spindle_waits returned them."""
        self.events = event_rows(plan)
        self.user_pause_rows = {p.row for p in plan.pauses} - wait_rows
        self.pause_rows = [p.row for p in plan.pauses]
        self.devices = devices
        self.path = folder / EVENTS_FILE
        self.status, self.resume, self.stop = status, resume, stop
        self.done: list[dict[str, Any]] = []
        self._next = 0
        self._finished = threading.Event()
        self._thread = threading.Thread(target=self._run, name="job-events", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def finish(self, drain: bool = False) -> None:
        """The job ended: stop the thread. ``drain`` (a completed job that leaves the spindle and
        outputs as it set them, service.machine_jobs): first do, in order and without waiting for
        the spindle, the events the thread had not got to (a job of a few rows can end between
        two polls)."""
        self._finished.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(2.0)
        if drain and not self._thread.is_alive():
            while self._next < len(self.events):
                self._next += 1
                self._do(self.events[self._next - 1], wait=False)

    def _ready(self, e: RowEvent, index: int, held_row: int | None) -> bool:
        """A wait row is done while the master holds there; any other event once playback is
        about to send its row (``index``: the last row sent, -1 before the first)."""
        if e.waits and e.row in self.pause_rows:
            return held_row == e.row
        return e.row <= index + 1

    def _run(self) -> None:
        while not self._finished.wait(POLL_S) and self._next < len(self.events):
            status = self.status()
            index = status.job_index if status.job_index is not None else -1
            held_row = self.pause_rows[status.pause] if status.phase == "held" and status.pause is not None \
                and status.pause < len(self.pause_rows) else None
            waited = False
            while self._next < len(self.events) and self._ready(self.events[self._next], index, held_row):
                e = self.events[self._next]
                self._next += 1
                if not self._do(e) or self._finished.is_set():
                    return
                waited = waited or (e.waits and e.row == held_row)
            if waited and held_row not in self.user_pause_rows:
                self.resume()

    def _do(self, e: RowEvent, wait: bool = True) -> bool:
        """Do one event; False when the job must end (the spindle did not come to speed)."""
        event, ok = e.event, True
        fields: dict[str, Any] = {"code": event.code, "at": str(event.source), "row": e.row}
        if event.kind is EventKind.SPINDLE and self.devices.spindle is not None:
            rpm = signed_rpm(event)
            self.devices.spindle.command_rpm(rpm)
            fields["rpm"] = rpm
            if e.waits and wait:
                timeout_s = self.devices.spindle.config.at_speed_timeout_s
                ok = self.devices.spindle.wait_at_speed(timeout_s, self._finished.is_set)
                actual = self.devices.spindle.status().actual_rpm
                fields.update(at_speed=ok, actual_rpm=actual)
                if not ok and not self._finished.is_set():
                    fault = self.devices.spindle.status().fault
                    self.stop(f"{event.source}: {event.code}: the spindle did not reach {rpm:g} rpm within "
                              f"{timeout_s:g} s (actual {actual if actual is not None else '?'} rpm"
                              f"{'; ' + fault if fault else ''})")
        elif event.kind is EventKind.COOLANT and self.devices.io is not None and event.coolant is not None:
            fields["outputs"] = self.devices.io.set_coolant(event.coolant)
        elif event.kind is EventKind.OUTPUT and self.devices.io is not None and event.output is not None:
            fields["outputs"] = self.devices.io.set_output_bit(event.output, bool(event.output_on))
        self.record(f"{event.kind.value}_event", fields)
        return ok or self._finished.is_set()

    def record(self, what: str, fields: dict[str, Any]) -> None:
        """One log line and one events.log line."""
        log.info(kv(what, **fields))
        entry = {"time": now_iso(), "event": what, **fields}
        self.done.append(entry)
        try:
            with self.path.open("a", encoding="utf-8") as f:
                f.write(kv(what, time=entry["time"], **fields) + "\n")
        except OSError as err:
            log.warning(kv("events_not_written", path=self.path, error=err))
