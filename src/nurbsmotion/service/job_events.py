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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from nurbsmotion.log import kv
from nurbsmotion.program import EventKind, ProgramEvent, SpindleDirection
from nurbsmotion.service.devices import MachineDevices
from nurbsmotion.service.job_common import JobPause, PlannedJob, spindle_wait_reason
from nurbsmotion.service.records import now_iso

log = logging.getLogger(__name__)

POLL_S = 0.01
# How long the end of a completed job waits for its last events (M5 M9 before M30): the thread
# may be inside an SDO transfer that waits behind the spindle monitor's reads (each up to its
# 3 s SDO time-out on a slow bus), so the 2 s it had were too short and M9 went missing.
DRAIN_WAIT_S = 10.0
STOP_WAIT_S = 2.0  # a job that did not complete: the thread is only stopped
EVENTS_FILE = "events.log"
DEVICE_EVENTS = (EventKind.SPINDLE, EventKind.COOLANT, EventKind.OUTPUT)  # done by the job's events


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
    return tuple(RowEvent(int(np.searchsorted(plan.trajectory.block, e.before_block, side="left")), e)
                 for e in program.events if e.kind in DEVICE_EVENTS)


def signed_rpm(event: ProgramEvent) -> float:
    """+rpm for M3 (cw), -rpm for M4 (ccw), 0 for M5."""
    rpm = event.spindle_rpm or 0.0
    return {SpindleDirection.CW: rpm, SpindleDirection.CCW: -rpm}.get(event.spindle, 0.0)  # type: ignore[arg-type]


def with_spindle_waits(plan: PlannedJob) -> PlannedJob:
    """The plan with a pause row (``spindle_wait``) at every spindle start/change inside the job,
    merged with the program's own pauses (one per row: the program's wins, the operator resumes
    it), sorted; the master's Playback keeps 0 <= row < last. A streamed job gets the same
    rows from its planner worker (service.planner_worker.pause_events)."""
    last = len(plan.counts) - 1
    rows = {p.row: p for p in plan.pauses}
    for e in event_rows(plan):
        if e.waits and 0 <= e.row < last and e.row not in rows:
            rows[e.row] = JobPause(e.row, spindle_wait_reason(e.event), spindle_wait=True)
    return replace(plan, pauses=tuple(rows[r] for r in sorted(rows)))


class JobEvents:
    """Runs one job's events on a thread; ``status()`` gives the master status (phase,
    job_index, pause), ``resume()`` continues the held job, ``stop(reason)`` ends it.

    ``events`` and ``pauses`` (the job's pause rows, in row order: the master's status.pause
    indexes them) may grow while the job runs (a streamed job's receiver appends them as
    chunks arrive, before the master can reach their rows); ``complete()`` says they will not
    grow any more."""

    def __init__(self, events: Sequence[RowEvent], pauses: Sequence[JobPause], complete: Callable[[], bool],
                 devices: MachineDevices, folder: Path, status: Callable[[], Any], resume: Callable[[], None],
                 stop: Callable[[str], None]) -> None:
        self.events = events
        self.pauses = pauses
        self.complete = complete
        self.devices = devices
        self.path = folder / EVENTS_FILE
        self.status, self.resume, self.stop = status, resume, stop
        self.done: list[dict[str, Any]] = []
        self._next = 0
        self._pause_rows: set[int] = set()  # rows of the pauses seen so far
        self._pauses_seen = 0
        self._finished = threading.Event()
        self._drain = False  # set by finish() before _finished
        self._given_up = threading.Event()  # finish() stopped waiting for the thread
        self._thread = threading.Thread(target=self._run, name="job-events", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def finish(self, drain: bool = False) -> None:
        """The job ended: stop the thread. ``drain`` (a completed job that leaves the spindle and
        outputs as it set them, service.machine_jobs): first do, in order and without waiting for
        the spindle, the events the thread had not got to (a job of a few rows can end between
        two polls). The thread does them itself after the transfer it may be in, so the order
        holds; those it cannot do within ``DRAIN_WAIT_S`` are given up with one line each."""
        self._drain = drain
        self._finished.set()
        if threading.current_thread() is self._thread:
            return
        if self._thread.is_alive():
            self._thread.join(DRAIN_WAIT_S if drain else STOP_WAIT_S)
        if self._thread.is_alive():
            self._given_up.set()
            log.warning(kv("job_events_late", events_left=len(self.events) - self._next,
                           waited_s=DRAIN_WAIT_S if drain else STOP_WAIT_S))
        elif drain:
            self._drain_rest()  # the thread ended before the job did (its events were all done)

    def _drain_rest(self) -> None:
        """The events not done yet, in order, without waiting for the spindle."""
        while self._next < len(self.events) and not self._given_up.is_set():
            self._next += 1
            self._do(self.events[self._next - 1], wait=False)
        for e in self.events[self._next:]:
            log.warning(kv("job_event_not_done", code=e.event.code, at=str(e.event.source)))

    def _ready(self, e: RowEvent, index: int, held_row: int | None) -> bool:
        """A spindle start at a pause row is done while the master holds there; any other event
        once playback is about to send its row (``index``: the last row sent, -1 before the first)."""
        if e.waits and e.row in self._pause_rows:
            return held_row == e.row
        return e.row <= index + 1

    def _held_pause(self, status: Any) -> JobPause | None:
        """The pause the master holds at (None while it is not held at one)."""
        pauses = self.pauses
        seen = len(pauses)
        self._pause_rows.update(p.row for p in pauses[self._pauses_seen:seen])
        self._pauses_seen = seen
        if status.phase == "held" and status.pause is not None and status.pause < len(pauses):
            return pauses[status.pause]
        return None

    def _run(self) -> None:
        self._play()
        if self._drain:
            self._drain_rest()

    def _play(self) -> None:
        """Each event at its row while the job runs, until the job ends."""
        while not self._finished.wait(POLL_S):
            complete = self.complete()  # read first: every event it covers is in the list below
            if self._next >= len(self.events) and complete:
                return
            status = self.status()
            index = status.job_index if status.job_index is not None else -1
            held = self._held_pause(status)
            held_row = held.row if held is not None else None
            waited = False
            while self._next < len(self.events) and self._ready(self.events[self._next], index, held_row):
                e = self.events[self._next]
                self._next += 1
                if not self._do(e) or self._finished.is_set():
                    return
                waited = waited or (e.waits and e.row == held_row)
            if waited and held is not None and held.spindle_wait:
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
