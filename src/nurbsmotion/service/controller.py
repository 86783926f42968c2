"""The daemon's one-job-at-a-time controller: submit, watch, stop, abort, reset, override,
status. Requests arrive from the control server's threads; one lock guards the job state.

States: ``idle`` (drives holding, ready for a job), ``running``, ``stopping`` (controlled
stop along the path in progress), ``fault`` (a fault not yet acknowledged by ``reset``).
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus.reports import FaultReport, JobResult, MasterStatus
from nurbsmotion.log import kv
from nurbsmotion.service.motion import JobHandle, MotionLink, Simulation
from nurbsmotion.service.planner import PlannedJob
from nurbsmotion.service.rate import effective_rate
from nurbsmotion.service.records import JobRecord, JobRecords

log = logging.getLogger(__name__)

Planner = Callable[[str, str, np.ndarray], PlannedJob]  # (name, text, start position mm) -> plan
OUTCOME_OF_RESULT = {"done": "completed", "stopped": "stopped", "aborted": "aborted", "faulted": "fault"}


class Refused(InputError):
    """A request that is well-formed but not possible now (busy, no job, in fault)."""


@dataclass
class ActiveJob:
    record: JobRecord
    name: str
    plan: PlannedJob
    handle: JobHandle | None = None
    stop_requested: str = ""  # '', 'stop', 'abort', 'shutdown'
    late_before: int = 0  # the link's cycle counters when the job started (outcome: the job's own)
    missed_before: int = 0
    started_s: float = field(default_factory=time.monotonic)
    watcher: threading.Thread | None = None


class Controller:
    def __init__(self, config: MachineConfig, link: MotionLink, planner: Planner, records: JobRecords,
                 simulation: Simulation | None = None) -> None:
        self.config = config
        self.link = link
        self.planner = planner
        self.records = records
        self.simulation = simulation
        self._lock = threading.Lock()
        self._job: ActiveJob | None = None
        self._planning = False
        self._last: dict[str, Any] | None = None
        self._faults_acknowledged = 0
        self._override = 1.0  # requested, as a fraction

    # ------------------------------------------------------------------ requests
    def submit(self, name: str, text: str) -> dict[str, Any]:
        """Parse, plan and check the program, record it, start streaming; reject with errors."""
        check_program_name(name)
        with self._lock:
            self._check_can_start()
            self._planning = True
        try:
            status = self.link.status()
            start_mm = self._held_position_mm(status)
            plan = self.planner(name, text, start_mm)
            record = self._record(name, text, plan)
            job = ActiveJob(record, name, plan, late_before=status.timing.late_cycles,
                            missed_before=status.timing.missed_cycles)
            if self.simulation is not None:
                self.simulation.clear_recordings()
            try:
                self._set_link_rate(plan)
                job.handle = self.link.stream(plan.counts)
            except (InputError, FieldbusError) as err:
                shutil.rmtree(record.folder, ignore_errors=True)  # nothing moved: no job happened
                raise InputError("submit", str(err)) from None
            job.watcher = threading.Thread(target=self._watch, args=(job,), name=f"job-{record.job_id}", daemon=True)
            with self._lock:
                self._job = job
            job.watcher.start()
        finally:
            with self._lock:
                self._planning = False
        log.info(kv("job_started", job=record.job_id, name=name, cycles=len(plan.counts)))
        return {"ok": True, "job": {"id": record.job_id, "folder": str(record.folder), "summary": plan.summary}}

    def stop(self) -> dict[str, Any]:
        job = self._running_job("stop")
        job.stop_requested = job.stop_requested or "stop"
        assert job.handle is not None
        job.handle.request_stop()
        return {"ok": True, "job": job.record.job_id, "state": "stopping"}

    def abort(self) -> dict[str, Any]:
        job = self._running_job("abort")
        job.stop_requested = "abort"
        assert job.handle is not None
        job.handle.abort()
        return {"ok": True, "job": job.record.job_id}

    def reset(self) -> dict[str, Any]:
        with self._lock:
            if self._job is not None or self._planning:
                raise Refused("reset", "a job is running; stop or abort it first")
        try:
            self.link.reset_faults()
        except FieldbusError as err:
            raise Refused("reset", str(err)) from None
        self._faults_acknowledged = len(self.link.status().faults)
        log.info(kv("faults_reset"))
        return {"ok": True, "state": self.state()}

    def override(self, percent: float) -> dict[str, Any]:
        if not 0.0 <= percent <= 150.0:
            raise InputError("field 'percent'", f"must be between 0 and 150, got {percent:g}")
        self._override = percent / 100.0
        job = self._job
        effective = self._set_link_rate(job.plan) if job is not None else self._override
        return {"ok": True, "requested_percent": percent, "effective_percent": round(effective * 100.0, 3)}

    def inject_fault(self, spec: str) -> dict[str, Any]:
        if self.simulation is None:
            raise Refused("field 'cmd'", "inject_fault is only available when the daemon simulates its drives "
                          "(simulate: true)")
        self.simulation.inject(spec)
        return {"ok": True}

    def job_info(self, job_id: str) -> dict[str, Any]:
        record = self.records.find(job_id)
        if record is None:
            raise InputError("field 'id'", f"no job {job_id!r} in {self.records.root}")
        active = self._job
        running = active is not None and active.record.job_id == job_id
        return {"ok": True, "job": {"id": job_id, "folder": str(record.folder), "running": running,
                                    "plan": record.plan(), "outcome": None if running else record.outcome()}}

    # ------------------------------------------------------------------ status
    def state(self, status: MasterStatus | None = None) -> str:
        status = status or self.link.status()
        job = self._job
        if len(status.faults) > self._faults_acknowledged or status.phase in ("quick_stop", "disabled", "offline"):
            return "stopping" if job is not None and status.phase == "stopping" else "fault"
        if job is None:
            return "idle"
        if job.stop_requested or status.phase == "stopping":
            return "stopping"
        return "running"

    def status(self) -> dict[str, Any]:
        status = self.link.status()
        axis_map = self.link.axis_map
        setpoints = np.array([[a.setpoint_counts for a in status.axes]])
        actual = np.array([[a.position_counts if a.position_counts is not None else a.setpoint_counts
                            for a in status.axes]])
        commanded_mm, actual_mm = axis_map.to_mm(setpoints)[0], axis_map.to_mm(actual)[0]
        axes = [{"name": a.name, "node": a.node_id, "drive_state": a.state, "statusword": a.statusword,
                 "commanded_mm": round(float(commanded_mm[i]), 6), "actual_mm": round(float(actual_mm[i]), 6),
                 "following_error_mm": None if a.following_error_counts is None else
                 round(a.following_error_counts * float(axis_map.sign[i]) / float(axis_map.counts_per_mm[i]), 6),
                 "emcy_count": a.emcy_count}
                for i, a in enumerate(status.axes)]
        t = status.timing
        job = self._job
        return {"ok": True, "state": self.state(status), "phase": status.phase, "job": self._job_progress(job, status),
                "override": self._override_status(job), "axes": axes,
                "cycles": {"count": t.cycles, "late": t.late_cycles, "missed": t.missed_cycles,
                           "send_errors": t.send_errors, "lateness_p99_ms": round(t.lateness_p99_s * 1e3, 3),
                           "lateness_max_ms": round(t.lateness_max_s * 1e3, 3)},
                "faults": [fault_dict(f) for f in status.faults[self._faults_acknowledged:]],
                "last_job": self._last, "simulate": self.simulation is not None}

    def _job_progress(self, job: ActiveJob | None, status: MasterStatus) -> dict[str, Any] | None:
        if job is None:
            return None
        total = len(job.plan.counts)
        index = status.job_index if status.job_index is not None and status.job_length == total else -1
        cycle = max(index + 1, 0)
        feed = float(job.plan.trajectory.feed_mm_s[min(max(index, 0), total - 1)]) * self._effective(job)
        return {"id": job.record.job_id, "name": job.name, "folder": str(job.record.folder), "cycle": cycle,
                "total": total, "percent": round(100.0 * cycle / total, 2), "feed_mm_s": round(feed, 3),
                "elapsed_s": round(time.monotonic() - job.started_s, 3)}

    def _override_status(self, job: ActiveJob | None) -> dict[str, Any]:
        out: dict[str, Any] = {"requested_percent": round(self._override * 100.0, 3),
                               "effective_percent": round(self._effective(job) * 100.0, 3)}
        if job is not None:
            out["max_percent"] = round(max(1.0, job.plan.max_rate) * 100.0, 3)
        return out

    def _effective(self, job: ActiveJob | None) -> float:
        return effective_rate(self._override, job.plan.max_rate) if job is not None else self._override

    # ------------------------------------------------------------------ job life
    def _check_can_start(self) -> None:
        if self._job is not None or self._planning:
            busy = self._job.record.job_id if self._job is not None else "another submission"
            raise Refused("submit", f"busy: job {busy} is running (one job at a time)")
        if self.state() == "fault":
            raise Refused("submit", "the drives are in fault; send reset first")

    def _record(self, name: str, text: str, plan: PlannedJob) -> JobRecord:
        """The job folder with program, plan and trace, complete before any motion."""
        record = None
        try:
            record = self.records.create(name, text)
            record.write_plan(plan.summary, plan.write_trace)
            return record
        except OSError as err:
            if record is not None:
                shutil.rmtree(record.folder, ignore_errors=True)
            raise InputError("data_dir", f"cannot write the job record in {self.records.root}: "
                             f"{err.strerror or err}") from None

    def _running_job(self, what: str) -> ActiveJob:
        job = self._job
        if job is None or job.handle is None:
            raise Refused(what, "no job is running")
        return job

    def _held_position_mm(self, status: MasterStatus) -> np.ndarray:
        held = np.array([[a.setpoint_counts for a in status.axes]])
        return self.link.axis_map.to_mm(held)[0]

    def _set_link_rate(self, plan: PlannedJob) -> float:
        rate = effective_rate(self._override, plan.max_rate)
        self.link.set_rate(rate)
        return rate

    def _watch(self, job: ActiveJob) -> None:
        """Wait for the end of the job, then write its outcome (and the drives' recordings)."""
        assert job.handle is not None
        result = None
        while result is None:
            result = job.handle.wait(1.0)
        outcome = self._outcome(job, result)
        if self.simulation is not None:
            try:
                outcome["drive_recordings"] = self.simulation.write_recordings(str(job.record.drives_dir))
            except OSError as err:
                log.warning(kv("recording_not_written", job=job.record.job_id, error=err))
        try:
            job.record.write_outcome(outcome)
        except OSError as err:  # the record is incomplete, but the daemon must stay usable
            log.error(kv("outcome_not_written", job=job.record.job_id, error=err))
        finally:
            log.info(kv("job_ended", job=job.record.job_id, outcome=outcome["outcome"]))
            with self._lock:
                self._last = {"id": job.record.job_id, "name": job.name, "folder": str(job.record.folder), **{
                    k: outcome[k] for k in ("outcome", "reason", "sent", "planned", "motion_time_s")}}
                self._job = None

    def _outcome(self, job: ActiveJob, result: JobResult) -> dict[str, Any]:
        outcome = OUTCOME_OF_RESULT.get(result.outcome, "fault")
        if result.faults:
            outcome = "fault"
        first = result.faults[0] if result.faults else None
        reason = str(first) if first else {"stop": "stopped on request", "shutdown": "stopped: the daemon was asked "
                                           "to end", "abort": "aborted on request (quick stop)"}.get(
            job.stop_requested, "")
        return {"outcome": outcome, "job": job.record.job_id, "name": job.name, "reason": reason,
                "fault": fault_dict(first) if first else None, "faults": [fault_dict(f) for f in result.faults],
                "sent": result.sent, "planned": result.length,
                "motion_time_s": round(time.monotonic() - job.started_s, 3),
                "missed_cycles": result.missed_cycles - job.missed_before,
                "late_cycles": result.late_cycles - job.late_before,
                "ended_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")}

    # ------------------------------------------------------------------ shutdown
    def shutdown(self, timeout_s: float = 10.0) -> None:
        """Controlled stop of the running job (outcome 'stopped'), then disable the drives."""
        job = self._job
        if job is not None and job.handle is not None:
            job.stop_requested = job.stop_requested or "shutdown"
            job.handle.request_stop()
            if job.watcher is not None:
                job.watcher.join(timeout_s)
        self.link.shutdown(timeout_s)


def check_program_name(name: str) -> None:
    """A program name is a file name: it appears in every error line and names the record file."""
    if not name or len(name) > 255 or any(ord(ch) < 32 or ch == "\x7f" for ch in name):
        raise InputError("field 'name'", "must be a file name of 1-255 printable characters")


def fault_dict(fault: FaultReport) -> dict[str, Any]:
    return {"node": fault.node_id, "axis": fault.axis, "kind": fault.kind, "code": fault.code,
            "cycle": fault.cycle, "message": fault.message}
