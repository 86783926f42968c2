"""What jobs do with the spindle and the machine I/O (service.devices): the controller's hooks.

- before a job: refuse it while the e-stop or a limit input is active; add the spindle's
  at-speed waits to its pause rows (service.job_events); enable a spindle an abort disabled;
- during it: its events at their rows (JobEvents); an e-stop or limit input, or a spindle
  that stops on its own, ends it with one line (``job.machine_fault``, the outcome's reason);
- at its end: the spindle ramps to 0 (completed, stopped) or gets a quick stop and is
  disabled (abort, fault); coolant off; a completed MDI and a completed or stopped jog leave
  the spindle and outputs as they are. An e-stop also quick-stops the axes without a job.

Every method is a no-op without devices, so the controller calls them unconditionally.
Jobs are service.active_job's ActiveJob (handle, record, plan, events, machine_fault, stop_requested).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from nurbsmotion.errors import FieldbusError
from nurbsmotion.log import kv
from nurbsmotion.service.active_job import JobPlan
from nurbsmotion.service.devices import MachineDevices
from nurbsmotion.service.job_events import JobEvents, RowEvent, event_rows, with_spindle_waits
from nurbsmotion.service.machine_io import AxisMotion, SafetyTrip
from nurbsmotion.service.job_common import JOG_NAME, MDI_NAME, PlannedJob
from nurbsmotion.service.streamed_job import StreamedJob

log = logging.getLogger(__name__)
DIRECTION_ROWS = 5  # axis_direction compares the set-points this many rows before and after
ENDED_SOFTLY = ("done", "stopped")  # master JobResult outcomes after which the spindle ramps down
KEEPS_DEVICES = {MDI_NAME: ("done",), JOG_NAME: ("done", "stopped")}  # job name -> outcomes that leave them on


class MachineJobs:
    def __init__(self, devices: MachineDevices | None, link: Any, running_job: Callable[[], Any]) -> None:
        self.devices = devices
        self.link = link
        self.running_job = running_job
        self.on_homing_trip: Callable[[str, str], None] = lambda axis, message: None  # set by the controller
        if devices is not None:
            devices.on_trip = self.trip
            devices.on_spindle_fault = self.spindle_fault
            devices.axis_direction = self.axis_direction

    # ------------------------------------------------------------------ before a job
    def spindle_commanded_rpm(self) -> float:
        """The spindle's commanded speed now (signed: + M3, - M4; 0 stopped or none): what
        the next program starts from (an earlier MDI's M3 keeps it turning)."""
        spindle = self.devices.spindle if self.devices is not None else None
        return spindle.status().commanded_rpm if spindle is not None else 0.0

    def start_refusal(self, jog: AxisMotion | None = None, ignored_axes: frozenset[str] = frozenset()) -> str | None:
        return self.devices.start_refusal(jog, ignored_axes) if self.devices is not None else None

    def reset_refusal(self) -> str | None:
        """Reset brings a lost io node up again (refused, with its bring-up line, if it cannot)
        and is refused while the e-stop input is active."""
        if self.devices is None:
            return None
        if (why := self.devices.revive_io()) is not None:
            return why
        io = self.devices.io
        return io.start_refusal() if io is not None and io.estop_active() else None

    def prepare(self, plan: JobPlan) -> JobPlan:
        """The plan with the spindle's wait rows (unchanged without devices; a streamed job's
        come with its chunks: the planner worker adds them, service.planner_worker)."""
        return with_spindle_waits(plan) if self.devices is not None and isinstance(plan, PlannedJob) else plan

    def ready(self) -> None:
        if self.devices is not None:
            self.devices.ready_for_job()

    # ------------------------------------------------------------------ during and after
    def start(self, job: Any) -> None:
        if self.devices is None or job.handle is None:
            return
        plan = job.plan
        if isinstance(plan, StreamedJob):  # events and pauses arrive with the chunks
            events: Sequence[RowEvent] = plan.row_events
            complete: Callable[[], bool] = plan.events_complete.is_set
        else:
            events, complete = event_rows(plan), lambda: True
        job.events = JobEvents(events, plan.pauses, complete, self.devices, job.record.folder, self.link.status,
                               job.handle.resume, lambda reason: self.stop_job(job, reason, abort=False))
        job.events.start()

    def end(self, job: Any, result: Any) -> None:
        """Spindle ramped down or quick-stopped and disabled, coolant off; one record line.
        An MDI that completed, or a jog that completed or was stopped, leaves them as they are
        (as LinuxCNC does: ``mdi "M3 S1000"`` keeps the spindle turning, ``mdi "M5"`` stops it)."""
        if self.devices is None:
            return
        hard = bool(job.machine_fault) or bool(result.faults) or result.outcome not in ENDED_SOFTLY
        if not hard and result.outcome in KEEPS_DEVICES.get(job.name, ()):
            if job.events is not None:
                job.events.finish(drain=True)
                job.events.record("devices_kept", self.devices.kept())
            return
        if job.events is not None:
            # a job run to its end: the events after its last move (M5 M9 before M30) are done too
            job.events.finish(drain=result.outcome == "done" and not job.machine_fault)
        try:
            self.devices.all_off(hard)
        except FieldbusError as err:
            log.error(kv("devices_not_stopped", job=job.record.job_id, error=err))
        if job.events is not None:
            job.events.record("devices_off", {"spindle": "quick stop, disabled" if hard else "ramped to 0",
                                              "coolant": "off"})

    def stop_job(self, job: Any, reason: str, abort: bool) -> None:
        """End ``job`` for a machine reason: ``reason`` becomes its outcome's one line."""
        if job.machine_fault or job.handle is None:
            return
        job.machine_fault = reason
        job.stop_requested = job.stop_requested or ("abort" if abort else "stop")
        if job.events is not None:  # the job's events.log and outcome: one line (logged there too)
            job.events.record("job_machine_fault", {"job": job.record.job_id, "reason": reason})
        else:
            log.warning(kv("job_machine_fault", job=job.record.job_id, reason=reason))
        if abort:
            job.handle.abort()
        else:
            job.handle.request_stop()

    def trip(self, trip: SafetyTrip) -> None:
        """An e-stop or limit input became active (receive thread: requests only, no waiting)."""
        log.warning(kv("io.trip", input=trip.input, axis=trip.axis or "-", reason=trip.message))
        job = self.running_job()
        if job is not None:
            self.stop_job(job, trip.message, abort=True)
        elif trip.axis is not None:
            self.on_homing_trip(trip.axis, trip.message)  # a homing under way stops (service.homing)
        if trip.axis is None:  # e-stop: every axis, with or without a job, then the spindle
            self.link.quick_stop(trip.message)
            if self.devices is not None:
                threading.Thread(target=self.devices.all_off, args=(True,), name="estop-devices", daemon=True).start()

    def axis_direction(self, axis: str) -> int:
        """+1 / -1: the way the running job moves ``axis`` (machine mm) around the set-point the
        master sends now (DIRECTION_ROWS either side); 0 without a job or at rest."""
        job = self.running_job()
        index = self.link.status().job_index
        axis_map = self.link.axis_map
        if job is None or index is None or axis not in axis_map.names:
            return 0
        i = axis_map.names.index(axis)
        return int(np.sign(job.plan.axis_step(i, index, DIRECTION_ROWS) * axis_map.sign[i]))

    def spindle_fault(self, message: str) -> None:
        """The spindle left OPERATION ENABLED on its own: the running job is aborted."""
        job = self.running_job()
        if job is not None and self.devices is not None and self.devices.spindle is not None:
            self.stop_job(job, f"spindle node {self.devices.spindle.config.node_id}: {message}", abort=True)

    def status(self) -> dict[str, Any]:
        return self.devices.status() if self.devices is not None else {}

    def close(self) -> None:
        if self.devices is not None:
            self.devices.close()
