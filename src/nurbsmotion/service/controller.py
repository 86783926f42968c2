"""The daemon's one-job-at-a-time controller: submit, watch, stop, abort, reset, override,
status. Requests arrive from the control server's threads; one lock guards the job state.

States: ``idle`` (drives holding, ready for a job), ``running``, ``stopping`` (controlled
stop along the path in progress), ``pausing`` (a hold's ramp to rest on the path), ``held``
(the job waits for ``resume``: a hold request or a program pause M0/M1/M6), ``fault`` (a
fault not yet acknowledged by ``reset``).
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
from nurbsmotion.errors import FieldbusError, InputError, Refused
from nurbsmotion.fieldbus.reports import FaultReport, JobResult, MasterStatus
from nurbsmotion.log import kv
from nurbsmotion.program import ReadOptions
from nurbsmotion.service.devices import MachineDevices
from nurbsmotion.service.feedback import FeedbackLog
from nurbsmotion.service.homing import Homing
from nurbsmotion.service.job_events import JobEvents
from nurbsmotion.service.jog import LEASE_REASON, Jogging
from nurbsmotion.service.machine_io import AxisMotion
from nurbsmotion.service.machine_jobs import MachineJobs
from nurbsmotion.service.machine_state import MachineState, cleared, save_state, selected, with_offset
from nurbsmotion.service.motion import JobHandle, MotionLink, Simulation
from nurbsmotion.service.job_common import MDI_NAME, PlannedJob
from nurbsmotion.service.streamed_job import StreamedJob
from nurbsmotion.service.rate import effective_rate
from nurbsmotion.service.start_line import resume_of, start_line_options
from nurbsmotion.service.record_config import config_dict
from nurbsmotion.service.records import TRAFFIC_FILE, JobRecord, JobRecords, now_iso

log = logging.getLogger(__name__)

JobPlan = PlannedJob | StreamedJob  # planned whole before motion, or while it runs (the daemon's lookahead jobs)
Planner = Callable[[str, str, np.ndarray, ReadOptions], JobPlan]  # (name, text, start mm, reader options) -> plan
SETTLE_S = 0.5  # the longest a job's end waits for the axes to reach their last set-point (final_position)
OUTCOME_OF_RESULT = {"done": "completed", "stopped": "stopped", "aborted": "aborted", "faulted": "fault"}


@dataclass
class ActiveJob:
    record: JobRecord
    name: str
    plan: JobPlan
    handle: JobHandle | None = None
    stop_requested: str = ""  # '', 'stop', 'abort', 'shutdown', 'jog_lease', or the reason itself (a sentence)
    late_before: int = 0  # the link's cycle counters when the job started (outcome: the job's own)
    missed_before: int = 0
    started_s: float = field(default_factory=time.monotonic)
    started_at: str = field(default_factory=now_iso)
    watcher: threading.Thread | None = None
    feedback: FeedbackLog | None = None
    overrides: list[dict[str, Any]] = field(default_factory=list)  # the override history of the job
    events: JobEvents | None = None  # spindle / coolant events at their rows (service.job_events)
    machine_fault: str = ""  # e-stop, limit input, spindle: the job's one-line reason

    @property
    def start_cycle(self) -> int:
        """Master cycle of the job's cycle 0 (-1 until the master took the job)."""
        return self.handle.start_cycle if self.handle is not None else -1


class Controller:
    def __init__(self, config: MachineConfig, link: MotionLink, planner: Planner, records: JobRecords,
                 simulation: Simulation | None = None, machine_state: MachineState | None = None,
                 devices: MachineDevices | None = None) -> None:
        self.config = config
        self.machine = MachineJobs(devices, link, lambda: self._job)  # spindle and machine I/O hooks
        self.machine_state = machine_state or MachineState()  # offsets and tool: persisted after each completed job
        self.link = link
        self.planner = planner
        self.records = records
        self.simulation = simulation
        self._lock = threading.Lock()
        self._job: ActiveJob | None = None
        self._planning = False
        self._last: dict[str, Any] | None = None
        self._last_job_faults: dict[tuple[int | None, str, int], int] = {}  # its faults -> its start cycle
        self._faults_acknowledged = 0
        self._override = 1.0  # requested, as a fraction
        self.homing = Homing(config, link)  # homed state, `home`, require_homing (service.homing)
        self.machine.on_homing_trip = self.homing.limit_tripped  # a limit input stops a homing too
        self.jogging = Jogging(self)  # `jog`, its lease (service.jog)

    # ------------------------------------------------------------------ requests
    def submit(self, name: str, text: str, keep_override: bool = False, block_delete: bool = True,
               optional_stop: bool = True, needs_homing: bool = True, jog: AxisMotion | None = None,
               start_line: int | None = None) -> dict[str, Any]:
        """Parse, plan and check the program, record it, start streaming; reject with errors.

        The program starts from the persisted offsets and tool with the block-delete and
        optional-stop switches given. The feed override goes back to 100 % for the new job
        unless ``keep_override``. ``needs_homing``: refused until homed when required (an
        incremental or continuous jog does not need it). ``jog``: the job is a jog of one axis in
        that direction, which may start while a limit switch it moves away from is active.
        ``start_line``: start the program from that line (program.gcode_start): the state there
        rebuilt, then the approach over ``machine.safe_z_mm``; the record and status name it."""
        check_program_name(name)
        with self._lock:
            try:
                self._check_can_start(jog)
                self._check_homing(needs_homing)
            except Refused as err:
                log.info(kv("submit_refused", name=name, error=err))
                raise
            self._planning = True
        try:
            status = self.link.status()
            try:
                start_mm, options = self.reading_start(block_delete, optional_stop, start_line, status)
                plan = self.planner(name, text, start_mm, options)
            except InputError as err:
                self._record_rejection(name, text, err)
                raise
            plan = self.machine.prepare(plan)  # the spindle's at-speed waits
            resume = resume_of(plan.program)
            if resume is not None:
                plan.summary["start_line"] = resume.as_dict()  # into plan.json
            try:
                record = self._record(name, text, plan)
            except InputError:
                plan.cancel()
                raise
            job = ActiveJob(record, name, plan, late_before=status.timing.late_cycles,
                            missed_before=status.timing.missed_cycles)
            if not keep_override and self._override != 1.0:
                self._override = 1.0
                log.info(kv("override_changed", requested_percent=100.0, reason="new_job"))
            if self.simulation is not None:
                self.simulation.clear_recordings()
            try:
                rate = self._set_link_rate(plan)
                self._record_traffic(record)
                job.feedback = self._record_feedback(record)
                job.overrides.append(self._override_entry(job, rate, "job_start", -1))
                self.machine.ready()
                job.handle = plan.start(self.link, self.homing.shift_counts)  # onto the offsets `method: here` set
                self.machine.start(job)
            except BaseException as err:  # any failure to start, an internal one too: no stray folder
                plan.cancel()
                self._stop_traffic()
                self._stop_feedback(job)
                plan.wait_closed()  # the planner worker writes the trace there until then
                shutil.rmtree(record.folder, ignore_errors=True)  # nothing moved: no job happened
                log.info(kv("submit_refused", name=name, error=err))
                if isinstance(err, (InputError, FieldbusError)):
                    raise InputError("submit", str(err)) from None
                raise
            job.watcher = threading.Thread(target=self._watch, args=(job,), name=f"job-{record.job_id}", daemon=True)
            with self._lock:
                self._job = job
            job.watcher.start()
        finally:
            with self._lock:
                self._planning = False
        log.info(kv("job_started", job=record.job_id, name=name, start_line=start_line, cycles=plan.total_cycles,
                    duration_s=plan.summary.get("duration_s"), streamed=isinstance(plan, StreamedJob),
                    override_percent=round(rate * 100.0, 3),
                    folder=record.folder))
        return {"ok": True, "job": {"id": record.job_id, "folder": str(record.folder), "summary": plan.summary}}

    def mdi(self, text: str) -> dict[str, Any]:
        """Run G-code lines typed by the operator as a job named ``<mdi>``: from where the axes
        hold (the reader's start is the commanded position, in the active work coordinates
        from the persisted offsets), with the same parsing, gate, planning and soft-limit
        checks as a program, recorded like one; the feed override is kept."""
        if not text.strip():
            raise InputError("field 'text'", "no G-code to run")
        try:
            return self.submit(MDI_NAME, text if text.endswith("\n") else text + "\n", keep_override=True)
        except Refused as err:
            raise Refused("mdi", err.message) from None

    def stop(self, reason: str = "stop") -> dict[str, Any]:
        """Controlled stop of the running job; ``reason``: a key of the outcome's reasons
        ('stop': "stopped on request") or the outcome's reason itself."""
        if self._job is None and self.homing.busy:  # stop the homing axis' search, restore its mode
            self.link.stop_homing()
            return {"ok": True, "job": None, "state": "homing"}
        job = self._running_job("stop")
        job.stop_requested = job.stop_requested or reason
        assert job.handle is not None
        job.handle.request_stop()
        return {"ok": True, "job": job.record.job_id, "state": "stopping"}

    def hold(self) -> dict[str, Any]:
        """Decelerate the running job to rest on its path (the stop's ramp) and keep it."""
        job = self._running_job("hold")
        if job.stop_requested:
            raise Refused("hold", f"job {job.record.job_id} is stopping")
        assert job.handle is not None
        job.handle.hold()
        log.info(kv("job_hold", job=job.record.job_id))
        return {"ok": True, "job": job.record.job_id, "state": "pausing"}

    def resume(self) -> dict[str, Any]:
        """Continue a held or paused job from where it rests."""
        job = self._running_job("resume")
        status = self.link.status()
        if status.phase != "held":
            raise Refused("resume", f"job {job.record.job_id} is not held (state {self.state(status)})")
        assert job.handle is not None
        job.handle.resume()
        log.info(kv("job_resume", job=job.record.job_id, pause=self._pause_reason(job, status) or "hold"))
        return {"ok": True, "job": job.record.job_id, "state": "running"}

    def abort(self) -> dict[str, Any]:
        if self._job is None and self.homing.busy:  # quick stop of every axis
            self.link.stop_homing(quick=True)
            return {"ok": True, "job": None}
        job = self._running_job("abort")
        job.stop_requested = "abort"
        assert job.handle is not None
        job.handle.abort()
        return {"ok": True, "job": job.record.job_id}

    def reset(self) -> dict[str, Any]:
        with self._lock:
            if self._job is not None or self._planning:
                raise Refused("reset", "a job is running; stop or abort it first")
            if self.homing.busy:
                raise Refused("reset", "homing is under way; stop or abort it first")
        if (refusal := self.machine.reset_refusal()) is not None:
            raise Refused("reset", refusal)
        try:
            self.link.reset_faults()
        except FieldbusError as err:
            raise Refused("reset", str(err)) from None
        self._faults_acknowledged = len(self.link.status().faults)
        log.info(kv("faults_reset"))
        return {"ok": True, "state": self.state()}

    def offsets(self, fields: dict[str, Any]) -> dict[str, Any]:
        """Show the offsets; with ``system`` (and x/y/z) set a work offset as G10 L2 does,
        with ``clear`` zero one (G92 as G92.1), with ``select`` make a system active.
        Changes are refused while a job runs (its program started from the old ones)."""
        changes = [k for k in ("system", "clear", "select") if k in fields]
        if any(k in fields for k in "xyz") and "system" not in fields:
            raise InputError("field 'system'", "required with x, y or z: the work offset to set (G54 ... G59.3)")
        if not changes:
            return {"ok": True, "offsets": self.machine_state.status()}
        with self._lock:
            if self._job is not None or self._planning:
                raise Refused("offsets", "a job is running; offsets change only between jobs")
            state = self.machine_state
            if "system" in fields:
                state = with_offset(state, fields["system"], tuple(fields.get(k) for k in "xyz"))  # type: ignore[arg-type]
            if "clear" in fields:
                state = cleared(state, fields["clear"])
            if "select" in fields:
                state = selected(state, fields["select"])
            self._persist(state, "offsets_command")
        return {"ok": True, "offsets": self.machine_state.status()}

    def _persist(self, state: MachineState, reason: str) -> None:
        """Keep ``state`` and write it to DATA_DIR/offsets.json (InputError naming data_dir if it cannot)."""
        try:
            save_state(self.config.data_dir, state)
        except OSError as err:
            raise InputError("data_dir", f"cannot write the offsets in {self.config.data_dir}: "
                             f"{err.strerror or err}") from None
        self.machine_state = state
        log.info(kv("offsets_saved", reason=reason, active=state.coordinates.active_name, tool=state.tool_in_spindle))

    def override(self, percent: float) -> dict[str, Any]:
        if not 0.0 <= percent <= 150.0:
            raise InputError("field 'percent'", f"must be between 0 and 150, got {percent:g}")
        self._override = percent / 100.0
        job = self._job
        effective = self._set_link_rate(job.plan) if job is not None else self._override
        if job is not None:
            index = self.link.status().job_index
            job.overrides.append(self._override_entry(job, effective, "request", -1 if index is None else index))
        log.info(kv("override_changed", requested_percent=percent, effective_percent=round(effective * 100.0, 3),
                    job=job.record.job_id if job is not None else "-"))
        return {"ok": True, "requested_percent": percent, "effective_percent": round(effective * 100.0, 3)}

    def home(self, axes: list[str]) -> dict[str, Any]:
        """Home ``axes`` (all with ``homing:`` when empty) in the configured order, on the
        homing thread (service.homing); refused while a job runs or in fault."""
        with self._lock:
            if self._job is not None or self._planning:
                busy = self._job.record.job_id if self._job is not None else "another submission"
                raise Refused("home", f"busy: job {busy} is running")
            if self.homing.busy:
                raise Refused("home", "homing is already under way")
            status = self.link.status()
            if self.state(status) == "fault":
                raise Refused("home", "the drives are in fault; send reset first")
            if (refusal := self.machine.start_refusal(None, self.homing.ignoring_limits(axes))) is not None:
                raise Refused("home", refusal)
            names = self.homing.start(axes, status.faults)
        return {"ok": True, "axes": names, "state": "homing"}

    def reading_start(self, block_delete: bool = True, optional_stop: bool = True, start_line: int | None = None,
                      status: MasterStatus | None = None) -> tuple[np.ndarray, ReadOptions]:
        """Where a program submitted now starts (the held position, machine mm) and the reader's
        options then: the persisted offsets and tool, the switches, the spindle as it runs, the
        start line (InputError when it cannot be started from there)."""
        start_mm = self._held_position_mm(status or self.link.status())
        options = self.machine_state.read_options(self.config.tool_table, block_delete, optional_stop,
                                                  self.machine.spindle_commanded_rpm())
        if start_line is not None:
            options = start_line_options(options, start_line, self.config)
        return start_mm, options

    def last_job(self) -> dict[str, Any] | None:
        """The last job that ended: id, name, outcome, reason, ... (None before the first)."""
        return self._last

    def idle(self) -> bool:
        """No job, no submission under way, no homing, no fault: a job may start now."""
        return self._job is None and not self._planning and self.state() == "idle"

    def held_position_mm(self) -> np.ndarray:
        """Where the axes hold, machine mm (axis map in force)."""
        return self._held_position_mm(self.link.status())

    def running_job_id(self) -> str | None:
        return self._running_id()

    def running_job_name(self) -> str | None:
        job = self._job
        return job.name if job is not None else None

    def inject_fault(self, spec: str) -> dict[str, Any]:
        if self.simulation is None:
            raise Refused("field 'cmd'", "inject_fault is only available when the daemon simulates its drives "
                          "(simulate: true)")
        self.simulation.inject(spec)
        return {"ok": True}

    def job_info(self, job_id: str) -> dict[str, Any]:
        return {"ok": True, "job": self.records.info(job_id, self._running_id())}

    def jobs(self, limit: int = 20) -> dict[str, Any]:
        """The newest ``limit`` records (newest first), one summary each."""
        return {"ok": True, **self.records.listing(limit, self._running_id())}

    def _running_id(self) -> str | None:
        job = self._job
        return job.record.job_id if job is not None else None

    # ------------------------------------------------------------------ status
    def state(self, status: MasterStatus | None = None) -> str:
        status = status or self.link.status()
        job = self._job
        if len(status.faults) > self._faults_acknowledged or status.phase in ("quick_stop", "disabled", "offline"):
            return "stopping" if job is not None and status.phase == "stopping" else "fault"
        if job is None:
            return "homing" if self.homing.busy else "idle"
        if job.stop_requested or status.phase == "stopping":
            return "stopping"
        if status.phase in ("pausing", "held"):
            return status.phase
        return "running"

    def status(self) -> dict[str, Any]:
        status = self.link.status()
        self.homing.forget_faulted(status.faults)
        axis_map = self.link.axis_map
        setpoints = np.array([[a.setpoint_counts for a in status.axes]])
        actual = np.array([[a.position_counts if a.position_counts is not None else a.setpoint_counts
                            for a in status.axes]])
        commanded_mm, actual_mm = axis_map.to_mm(setpoints)[0], axis_map.to_mm(actual)[0]
        axes = [{"name": a.name, "node": a.node_id, "drive_state": a.state, "statusword": a.statusword,
                 "commanded_mm": round(float(commanded_mm[i]), 6), "actual_mm": round(float(actual_mm[i]), 6),
                 "following_error_mm": None if a.following_error_counts is None else
                 round(a.following_error_counts * float(axis_map.sign[i]) / float(axis_map.counts_per_mm[i]), 6),
                 "emcy_count": a.emcy_count, "soft_limits_mm": _limits(self.config.axes[i].soft_limits_mm)}
                for i, a in enumerate(status.axes)]
        t = status.timing
        job = self._job
        return {"ok": True, "state": self.state(status), "phase": status.phase, "job": self._job_progress(job, status),
                "override": self._override_status(job), "axes": axes,
                "cycles": {"count": t.cycles, "late": t.late_cycles, "missed": t.missed_cycles,
                           "send_errors": t.send_errors, "lateness_p99_ms": round(t.lateness_p99_s * 1e3, 3),
                           "lateness_max_ms": round(t.lateness_max_s * 1e3, 3)},
                "faults": [self._fault_record(f, status, job.start_cycle if job is not None else
                                              self._last_job_faults.get((f.node_id, f.kind, f.cycle)))
                           for f in status.faults[self._faults_acknowledged:]],
                "last_job": self._last, "simulate": self.simulation is not None,
                "coordinates": self.machine_state.status(), "homing": self.homing.status(),
                **self.machine.status()}

    def _job_progress(self, job: ActiveJob | None, status: MasterStatus) -> dict[str, Any] | None:
        if job is None:
            return None
        total = job.plan.total_cycles  # None while a streamed job is still being planned
        mine = status.job_index is not None and (total is None and job.start_cycle >= 0 or status.job_length == total)
        index = status.job_index if mine and status.job_index is not None else self._ended_index(job)
        cycle = max(index + 1, 0)
        rate = status.rate if status.rate is not None else self._effective(job)  # 0 while held
        feed = job.plan.feed_at(index) * rate
        reached = self._line_reached(job, index)
        pause = job.plan.pauses[status.pause] if status.pause is not None else None
        return {"paused": pause.reason if pause else None, "tool": pause.tool if pause else None,"id": job.record.job_id, "name": job.name, "folder": str(job.record.folder), "cycle": cycle,
                "total": total if total is not None else max(status.job_length or 0, cycle),
                "percent": round(job.plan.percent_at(index), 2), "planned_all": total is not None,
                "feed_mm_s": round(feed, 3),
                "override_percent": round(self._effective(job) * 100.0, 3),
                "line": reached["where"] if reached else None, "started_at": job.started_at,
                "start_line": getattr(resume_of(job.plan.program), "line", None),
                "elapsed_s": round(time.monotonic() - job.started_s, 3)}

    @staticmethod
    def _ended_index(job: ActiveJob) -> int:
        """The last planned set-point sent of a job the master has let go of (it ended; its
        record is being written), so the progress shows where it stopped, not cycle 0; -1
        before it started."""
        result = getattr(job.handle, "result", None)
        return result.sent - 1 if result is not None else -1

    @staticmethod
    def _pause_reason(job: ActiveJob, status: MasterStatus) -> str | None:
        return job.plan.pauses[status.pause].reason if status.pause is not None else None

    def _override_status(self, job: ActiveJob | None) -> dict[str, Any]:
        out: dict[str, Any] = {"requested_percent": round(self._override * 100.0, 3),
                               "effective_percent": round(self._effective(job) * 100.0, 3)}
        if job is not None:
            out["max_percent"] = round(max(1.0, job.plan.max_rate) * 100.0, 3)
        return out

    def _effective(self, job: ActiveJob | None) -> float:
        return effective_rate(self._override, job.plan.max_rate) if job is not None else self._override

    # ------------------------------------------------------------------ job life
    def _check_can_start(self, jog: AxisMotion | None = None) -> None:
        if self._job is not None or self._planning:
            busy = self._job.record.job_id if self._job is not None else "another submission"
            raise Refused("submit", f"busy: job {busy} is running (one job at a time)")
        if (refusal := self.machine.start_refusal(jog)) is not None:
            raise Refused("submit", refusal)
        if self.state() == "fault":
            raise Refused("submit", "the drives are in fault; send reset first")

    def _check_homing(self, needs_homing: bool) -> None:
        self.homing.forget_faulted(self.link.status().faults)
        why = self.homing.refusal(needs_homing)
        if why is not None:
            raise Refused("submit", why)

    def _record(self, name: str, text: str, plan: JobPlan) -> JobRecord:
        """The job folder with program, configuration and plan before any motion (a streamed
        job's trace follows as it is planned)."""
        record = None
        try:
            record = self.records.create(name, text)
            record.write_config(config_dict(self.config, self.link.axis_map.offset_counts))
            plan.write_records(record)
            return record
        except OSError as err:
            if record is not None:
                shutil.rmtree(record.folder, ignore_errors=True)
            raise InputError("data_dir", f"cannot write the job record in {self.records.root}: "
                             f"{err.strerror or err}") from None

    def _record_rejection(self, name: str, text: str, err: InputError) -> None:
        """A rejected program leaves a record (program + error lines) and one log line."""
        errors = str(err).splitlines()
        job_id = "-"
        try:
            job_id = self.records.create_rejected(name, text, errors).job_id
        except OSError as os_err:
            log.warning(kv("rejection_not_recorded", name=name, error=os_err.strerror or os_err))
        log.info(kv("submit_rejected", name=name, record=job_id, errors=len(errors), first=errors[0]))

    def _record_feedback(self, record: JobRecord) -> FeedbackLog | None:
        """feedback.csv: every TPDO1 of the job (service.feedback), from before the first set-point
        (monitoring.feedback_log: false records none)."""
        if not self.config.monitoring.feedback_log:
            return None
        try:
            feedback = FeedbackLog(record.feedback_path, self.link.axis_map)
        except OSError as err:
            log.warning(kv("feedback_not_recorded", job=record.job_id, error=err.strerror or err))
            return None
        self.link.record_feedback(feedback.add)
        return feedback

    def _stop_feedback(self, job: ActiveJob) -> None:
        if job.feedback is None:
            return
        self.link.record_feedback(None)
        try:
            job.feedback.close(max(job.start_cycle, 0))
        except OSError as err:
            log.warning(kv("feedback_not_written", job=job.record.job_id, error=err.strerror or err))

    def _flush_feedback(self, job: ActiveJob) -> None:
        if job.feedback is not None and job.start_cycle >= 0:
            try:
                job.feedback.flush(job.start_cycle)
            except OSError as err:
                log.warning(kv("feedback_not_written", job=job.record.job_id, error=err.strerror or err))
                self.link.record_feedback(None)
                job.feedback = None

    def _override_entry(self, job: ActiveJob, effective: float, by: str, index: int) -> dict[str, Any]:
        """One entry of the job's override history: when (seconds since the job started and
        the planned set-point reached), who, requested and effective percent."""
        return {"at_s": round(time.monotonic() - job.started_s, 3), "setpoint": index, "by": by,
                "requested_percent": round(self._override * 100.0, 3),
                "effective_percent": round(effective * 100.0, 3)}

    def _record_traffic(self, record: JobRecord) -> None:
        """monitoring.traffic_log: every bus frame of the job into its folder (log: candump,
        asc: Vector ASCII)."""
        fmt = self.config.monitoring.traffic_log
        if fmt != "none":
            self.link.record_traffic(str(record.folder / f"{TRAFFIC_FILE}.{fmt}"))

    def _stop_traffic(self) -> None:
        if self.config.monitoring.traffic_log != "none":
            try:
                self.link.record_traffic(None)
            except FieldbusError as err:
                log.warning(kv("traffic_log_not_closed", error=err))

    def _running_job(self, what: str) -> ActiveJob:
        job = self._job
        if job is None or job.handle is None:
            raise Refused(what, "no job is running")
        return job

    def _held_position_mm(self, status: MasterStatus) -> np.ndarray:
        held = np.array([[a.setpoint_counts for a in status.axes]])
        return self.link.axis_map.to_mm(held)[0]

    def _set_link_rate(self, plan: JobPlan) -> float:
        rate = effective_rate(self._override, plan.max_rate)
        self.link.set_rate(rate)
        return rate

    def _watch(self, job: ActiveJob) -> None:
        """Wait for the end of the job, then write its outcome (and the drives' recordings)."""
        assert job.handle is not None
        result = None
        while result is None:
            result = job.handle.wait(1.0)
            self._flush_feedback(job)
        job.plan.cancel()  # a streamed job's planner stops (the job ended)
        self.machine.end(job, result)
        status, settled = self._settled_status()
        self._stop_feedback(job)  # after the settling: feedback.csv shows the axes come to rest
        outcome = self._outcome(job, result, status, settled)
        self._stop_traffic()
        if self.simulation is not None:
            try:
                outcome["drive_recordings"] = self.simulation.write_recordings(str(job.record.drives_dir))
            except OSError as err:
                log.warning(kv("recording_not_written", job=job.record.job_id, error=err))
        self._keep_program_state(job, outcome["outcome"])
        try:
            job.plan.finish_records(job.record)
        except OSError as err:
            log.error(kv("plan_not_written", job=job.record.job_id, error=err))
        try:
            job.record.write_outcome(outcome)
        except OSError as err:  # the record is incomplete, but the daemon must stay usable
            log.error(kv("outcome_not_written", job=job.record.job_id, error=err))
        finally:
            reached = outcome["line_reached"]
            log.info(kv("job_ended", job=job.record.job_id, name=job.name, outcome=outcome["outcome"], sent=outcome["sent"],
                        planned=outcome["planned"], line=reached["where"] if reached else "-",
                        motion_time_s=outcome["motion_time_s"], reason=outcome["reason"] or "-"))
            with self._lock:
                self._last_job_faults = {(f["node"], f["kind"], f["master_cycle"]): job.start_cycle
                                         for f in outcome["faults"]}
                self._last = {"id": job.record.job_id, "name": job.name, "folder": str(job.record.folder), **{
                    k: outcome[k] for k in ("outcome", "reason", "sent", "planned", "motion_time_s")},
                    "line_reached": reached["where"] if reached else None}
                self._job = None

    def _keep_program_state(self, job: ActiveJob, outcome: str) -> None:
        """A completed program's final offsets and tool become the machine's (offsets.json).
        A job that ended early keeps the state it started from: the reader's end state
        includes G10/G92 lines the machine never reached."""
        program = job.plan.program
        if outcome != "completed" or program is None or program.coordinates is None:
            return
        tool = program.tool_at_end if program.tool_at_end is not None else self.machine_state.tool_in_spindle
        state = MachineState(program.coordinates, tool)
        if state == self.machine_state:
            return
        try:
            self._persist(state, f"job {job.record.job_id} completed")
        except InputError as err:
            log.error(kv("offsets_not_saved", job=job.record.job_id, error=err))

    def _settled_status(self) -> tuple[MasterStatus, bool]:
        """The status once every axis' position actual is within one count of its set-point
        (the servo caught up; after a quick stop the master's set-point follows the actual),
        or after SETTLE_S: (status, settled)."""
        deadline = time.monotonic() + SETTLE_S
        while True:
            status = self.link.status()
            settled = all(a.position_counts is not None and abs(a.position_counts - a.setpoint_counts) <= 1
                          for a in status.axes)
            if settled or time.monotonic() >= deadline:
                return status, settled
            time.sleep(self.config.cycle_period_s)

    def _outcome(self, job: ActiveJob, result: JobResult, status: MasterStatus, settled: bool) -> dict[str, Any]:
        outcome = OUTCOME_OF_RESULT.get(result.outcome, "fault")
        if result.faults:
            outcome = "fault"
        faults = [self._fault_record(f, status, job.start_cycle) for f in result.faults]
        if job.machine_fault:
            outcome = "fault"
        reason = job.machine_fault or faults[0]["message"] if job.machine_fault or faults else {
            "stop": "stopped on request", "shutdown": "stopped: the daemon was asked to end",
            "abort": "aborted on request (quick stop)", "jog_lease": LEASE_REASON}.get(job.stop_requested, job.stop_requested)
        cut_short = job.plan.end_reason(getattr(job.handle, "fell_behind_row", -1))
        if cut_short and outcome == "completed":  # the planner stopped the job (failed or fell behind)
            outcome, reason = "stopped", cut_short
            log.warning(kv("job_cut_short", job=job.record.job_id, reason=cut_short))
        return {"outcome": outcome, "job": job.record.job_id, "name": job.name, "reason": reason,
                "start_line": getattr(resume_of(job.plan.program), "line", None),
                "fault": faults[0] if faults else None, "faults": faults,
                "sent": result.sent, "planned": result.length,
                "line_reached": self._line_reached(job, result.sent - 1),
                "final_position": self._positions_mm(status), "settled": settled,
                "overrides": job.overrides, "machine_events": job.events.done if job.events is not None else [],
                "feedback_rows": job.feedback.rows if job.feedback is not None else None,
                "motion_time_s": round(time.monotonic() - job.started_s, 3),
                "missed_cycles": result.missed_cycles - job.missed_before,
                "late_cycles": result.late_cycles - job.late_before,
                "start_cycle": job.start_cycle, "started_at": job.started_at, "ended_at": now_iso()}

    def _line_reached(self, job: ActiveJob, index: int) -> dict[str, Any] | None:
        """The program line of planned set-point ``index`` (None before the first one)."""
        program, block = job.plan.program, job.plan.block_at(index)
        if program is None or block is None or not program.blocks:  # no motion: no line reached
            return None
        source = program.blocks[block].source
        return {"where": str(source), "line": source.line, "text": source.text, "block": block, "setpoint": index}

    def _positions_mm(self, status: MasterStatus) -> dict[str, dict[str, float | None]]:
        """Per axis: the last set-point sent and the drive's position actual (TPDO1), in mm."""
        axis_map = self.link.axis_map
        commanded = axis_map.to_mm(np.array([[a.setpoint_counts for a in status.axes]]))[0]
        actual = axis_map.to_mm(np.array([[a.position_counts or 0 for a in status.axes]]))[0]
        return {a.name: {"commanded_mm": round(float(commanded[i]), 6),
                         "actual_mm": None if a.position_counts is None else round(float(actual[i]), 6)}
                for i, a in enumerate(status.axes)}

    def _fault_record(self, fault: FaultReport, status: MasterStatus, start_cycle: int | None = None) -> dict[str, Any]:
        """fault_record() with the axis' scale and last EMCY code from the status."""
        axis = next((a for a in status.axes if a.node_id == fault.node_id), None)
        config = next((a for a in self.config.axes if a.node_id == fault.node_id), None)
        mm_per_count = None if config is None else (-1.0 if config.invert else 1.0) / config.counts_per_mm
        return fault_record(fault, start_cycle, mm_per_count, axis.last_emcy_code if axis else None,
                            axis.statusword if axis else None)

    # ------------------------------------------------------------------ shutdown
    def shutdown(self, timeout_s: float = 10.0) -> None:
        """Controlled stop of the running job (outcome 'stopped'), then disable the drives."""
        job = self._job
        if job is not None and job.handle is not None:
            job.stop_requested = job.stop_requested or "shutdown"
            job.handle.request_stop()
            if job.watcher is not None:
                job.watcher.join(timeout_s)
        self.machine.close()
        self.link.shutdown(timeout_s)


def check_program_name(name: str) -> None:
    """A program name is a file name: it appears in every error line and names the record file."""
    if not name or len(name) > 255 or any(ord(ch) < 32 or ch == "\x7f" for ch in name):
        raise InputError("field 'name'", "must be a file name of 1-255 printable characters")


def fault_record(fault: FaultReport, start_cycle: int | None, mm_per_count: float | None,
                 last_emcy: int | None, statusword: int | None) -> dict[str, Any]:
    """A fault as records and the status show it.

    ``code``: the CiA-301 EMCY error code (``emcy``; for ``fault_bit`` the axis' last EMCY,
    if any), else None. ``measured``: the value that tripped it, in its own field: the
    following error in counts and mm, the NMT state a heartbeat reported, the statusword.
    ``cycle``: job-relative (0 = the cycle that sent the job's first set-point) when
    ``start_cycle`` is known, else the master's; ``master_cycle`` always the master's.
    """
    code: int | None = None
    measured: dict[str, Any] | None = None
    if fault.kind == "emcy":
        code = fault.code
    elif fault.kind == "following_error" and fault.code:
        measured = {"following_error_counts": fault.code,
                    "following_error_mm": None if mm_per_count is None else round(fault.code * mm_per_count, 6)}
    elif fault.kind == "heartbeat" and fault.code >= 0:
        measured = {"nmt_state": fault.code}
    elif fault.kind == "fault_bit":
        code = last_emcy if last_emcy and last_emcy & 0xFF00 else None
        measured = None if statusword is None else {"statusword": statusword}
    elif fault.kind == "bringup":
        measured = {"statusword": fault.code}
    cycle, message = fault.cycle, fault.message
    if start_cycle is not None and start_cycle >= 0 and fault.cycle >= 0:
        cycle = fault.cycle - start_cycle
        message = message.replace(f"at cycle {fault.cycle}", f"at job cycle {cycle}")
    return {"node": fault.node_id, "axis": fault.axis, "kind": fault.kind, "code": code,
            "code_hex": None if code is None else f"0x{code:04X}", "measured": measured, "cycle": cycle,
            "master_cycle": fault.cycle, "message": message}


def _limits(pair: tuple[float, float] | None) -> list[float] | None:
    return None if pair is None else [float(pair[0]), float(pair[1])]
