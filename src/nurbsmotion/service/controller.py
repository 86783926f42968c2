"""The daemon's one-job-at-a-time controller: submit, watch, stop, abort, reset, override,
status. Requests arrive from the control server's threads; one lock guards the job state.

States: ``idle`` (drives holding, ready for a job), ``running``, ``stopping`` (controlled
stop along the path in progress), ``pausing`` (a hold's ramp to rest on the path), ``held``
(the job waits for ``resume``: a hold request or a program pause M0/M1/M6), ``fault`` (a
fault not yet acknowledged by ``reset``).

The controller keeps the job state and the requests; its parts: the job's record folder
(job_files), the feed override (feed_override), the progress the status shows
(job_progress), how a job ended (job_outcome), the persisted offsets and tool
(machine_state_store); the job itself is active_job's ActiveJob.
"""

from __future__ import annotations

import logging
import shutil
import threading
from typing import Any, Callable

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError, Refused
from nurbsmotion.fieldbus.reports import MasterStatus
from nurbsmotion.log import kv
from nurbsmotion.program import ReadOptions
from nurbsmotion.service.active_job import ActiveJob, JobPlan, running_job
from nurbsmotion.service.devices import MachineDevices
from nurbsmotion.service.feed_override import FeedOverride
from nurbsmotion.service.homing import Homing
from nurbsmotion.service.job_files import JobFiles
from nurbsmotion.service.job_outcome import JobOutcome
from nurbsmotion.service.job_progress import job_progress, pause_reason
from nurbsmotion.service.jog import Jogging
from nurbsmotion.service.machine_io import AxisMotion
from nurbsmotion.service.machine_jobs import MachineJobs
from nurbsmotion.service.machine_state import MachineState, cleared, selected, with_offset
from nurbsmotion.service.machine_state_store import MachineStateStore
from nurbsmotion.service.motion import MotionLink, Simulation
from nurbsmotion.service.program_file import ProgramFile
from nurbsmotion.service.job_common import MDI_NAME, RunningJob, running_job_id
from nurbsmotion.service.streamed_job import StreamedJob
from nurbsmotion.service.start_line import resume_of, start_line_options
from nurbsmotion.fieldbus.cycle_slack import CycleSlack, run_steps
from nurbsmotion.steps import Steps
from nurbsmotion.service.records import JobRecords

log = logging.getLogger(__name__)

FAST_FIELDS = ("ok", "state", "phase", "job", "axes", "cycles", "faults")  # Controller.status(fast_only=True)
Planner = Callable[[str, "str | ProgramFile", np.ndarray, ReadOptions], JobPlan]  # (name, text or its file, start mm, reader options) -> plan


class Controller:
    def __init__(self, config: MachineConfig, link: MotionLink, planner: Planner, records: JobRecords,
                 simulation: Simulation | None = None, machine_state: MachineState | None = None,
                 devices: MachineDevices | None = None) -> None:
        self.config = config
        self.machine = MachineJobs(devices, link, lambda: self._job)  # spindle and machine I/O hooks
        self.state_store = MachineStateStore(config, machine_state or MachineState())  # offsets and tool, persisted
        self.link = link
        self.planner = planner
        self.records = records
        self.files = JobFiles(config, link, records)  # the job's record folder, feedback.csv, traffic log
        self.outcomes = JobOutcome(config, link)  # how a job ended (outcome.json), faults as the status shows them
        self.simulation = simulation
        self._lock = threading.Lock()
        self._job: ActiveJob | None = None
        self._planning = False
        self._last: dict[str, Any] | None = None
        self._last_job_faults: dict[tuple[int | None, str, int], int] = {}  # its faults -> its start cycle
        self._faults_acknowledged = 0
        self.feed_override = FeedOverride(link)  # requested, and in effect for the job
        self.homing = Homing(config, link)  # homed state, `home`, require_homing (service.homing)
        self.machine.on_homing_trip = self.homing.limit_tripped  # a limit input stops a homing too
        self.jogging = Jogging(self)  # `jog`, its lease (service.jog)

    # ------------------------------------------------------------------ requests
    def submit(self, name: str, text: str | ProgramFile, keep_override: bool = False, block_delete: bool = True,
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
                check_homing(self.homing, self.link.status(), needs_homing)
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
                self.files.record_rejection(name, text, err)
                raise
            plan = self.machine.prepare(plan)  # the spindle's at-speed waits
            resume = resume_of(plan.program)
            if resume is not None:
                plan.summary["start_line"] = resume.as_dict()  # into plan.json
            try:
                record = self.files.record(name, text, plan)
            except InputError:
                plan.cancel()
                raise
            job = ActiveJob(record, name, plan, late_before=status.timing.late_cycles,
                            missed_before=status.timing.missed_cycles)
            if not keep_override and self.feed_override.requested != 1.0:
                self.feed_override.requested = 1.0
                log.info(kv("override_changed", requested_percent=100.0, reason="new_job"))
            if self.simulation is not None:
                self.simulation.clear_recordings()
            try:
                rate = self.feed_override.set_link_rate(plan)
                self.files.record_traffic(record)
                job.feedback = self.files.record_feedback(record)
                job.overrides.append(self.feed_override.entry(job, rate, "job_start", -1))
                self.machine.ready()
                job.handle = plan.start(self.link, self.homing.shift_counts)  # onto the offsets `method: here` set
                self.machine.start(job)
            except BaseException as err:  # any failure to start, an internal one too: no stray folder
                plan.cancel()
                self.files.stop_traffic()
                self.files.stop_feedback(job)
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
        job = running_job(self._job, "stop")
        job.stop_requested = job.stop_requested or reason
        assert job.handle is not None
        job.handle.request_stop()
        return {"ok": True, "job": job.record.job_id, "state": "stopping"}

    def hold(self) -> dict[str, Any]:
        """Decelerate the running job to rest on its path (the stop's ramp) and keep it."""
        job = running_job(self._job, "hold")
        if job.stop_requested:
            raise Refused("hold", f"job {job.record.job_id} is stopping")
        assert job.handle is not None
        job.handle.hold()
        log.info(kv("job_hold", job=job.record.job_id))
        return {"ok": True, "job": job.record.job_id, "state": "pausing"}

    def resume(self) -> dict[str, Any]:
        """Continue a held or paused job from where it rests."""
        job = running_job(self._job, "resume")
        status = self.link.status()
        if status.phase != "held":
            raise Refused("resume", f"job {job.record.job_id} is not held (state {self.state(status)})")
        assert job.handle is not None
        job.handle.resume()
        log.info(kv("job_resume", job=job.record.job_id, pause=pause_reason(job, status) or "hold"))
        return {"ok": True, "job": job.record.job_id, "state": "running"}

    def abort(self) -> dict[str, Any]:
        if self._job is None and self.homing.busy:  # quick stop of every axis
            self.link.stop_homing(quick=True)
            return {"ok": True, "job": None}
        job = running_job(self._job, "abort")
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
            return {"ok": True, "offsets": self.state_store.state.status()}
        with self._lock:
            if self._job is not None or self._planning:
                raise Refused("offsets", "a job is running; offsets change only between jobs")
            state = self.state_store.state
            if "system" in fields:
                state = with_offset(state, fields["system"], tuple(fields.get(k) for k in "xyz"))  # type: ignore[arg-type]
            if "clear" in fields:
                state = cleared(state, fields["clear"])
            if "select" in fields:
                state = selected(state, fields["select"])
            self.state_store.persist(state, "offsets_command")
        return {"ok": True, "offsets": self.state_store.state.status()}

    def override(self, percent: float) -> dict[str, Any]:
        if not 0.0 <= percent <= 150.0:
            raise InputError("field 'percent'", f"must be between 0 and 150, got {percent:g}")
        self.feed_override.requested = percent / 100.0
        job = self._job
        effective = self.feed_override.set_link_rate(job.plan) if job is not None else self.feed_override.requested
        if job is not None:
            index = self.link.status().job_index
            job.overrides.append(self.feed_override.entry(job, effective, "request", -1 if index is None else index))
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
        start_mm = held_position_mm(self.link, status or self.link.status())
        options = self.state_store.state.read_options(self.config.tool_table, block_delete, optional_stop,
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
        return held_position_mm(self.link, self.link.status())

    def running_job(self) -> RunningJob | None:
        """The job running now (None: none)."""
        job = self._job
        return RunningJob(job.record.job_id, job.name) if job is not None else None

    def inject_fault(self, spec: str) -> dict[str, Any]:
        if self.simulation is None:
            raise Refused("field 'cmd'", "inject_fault is only available when the daemon simulates its drives "
                          "(simulate: true)")
        self.simulation.inject(spec)
        return {"ok": True}

    def job_info(self, job_id: str) -> dict[str, Any]:
        return {"ok": True, "job": self.records.info(job_id, running_job_id(self.running_job()))}

    def jobs(self, limit: int = 20) -> dict[str, Any]:
        """The newest ``limit`` records (newest first), one summary each."""
        return {"ok": True, **self.records.listing(limit, running_job_id(self.running_job()))}

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

    def status(self, fast_only: bool = False) -> dict[str, Any]:
        """The ``status`` answer (status_steps, read at once)."""
        return run_steps(self.status_steps(fast_only))

    def status_steps(self, fast_only: bool = False) -> Steps[dict[str, Any]]:
        """The ``status`` answer, read in short steps (a generator: it yields between the parts
        and returns the answer). ``fast_only``: only FAST_FIELDS, those that change every
        cycle while the machine moves (axis positions, cycle counters, the job's progress)
        or with its state; the status publisher reads these at the subscribers' rate and the
        rest after events (service.subscriptions), each step in the cycle thread's slack. A
        fast read's ``cycles`` has the lateness p99 of the last whole read (the percentile
        was most of the master's read)."""
        status = self.link.status(percentiles=not fast_only)
        yield None
        self.homing.forget_faulted(status.faults)
        job = self._job
        progress = job_progress(job, status, self.feed_override.effective(job))
        yield None
        axes = axes_status(status, self.link.axis_map, self.config)
        yield None
        fast = {"ok": True, "state": self.state(status), "phase": status.phase, "job": progress, "axes": axes,
                "cycles": {**cycles_status(status), **slack_status(self.link.cycle_slack)},
                "faults": [self.outcomes.fault_record(f, status, job.start_cycle if job is not None else
                                                      self._last_job_faults.get((f.node_id, f.kind, f.cycle)))
                           for f in status.faults[self._faults_acknowledged:]]}
        if fast_only:
            return fast
        yield None
        return {**fast, "override": self.feed_override.status(job), "last_job": self._last,
                "simulate": self.simulation is not None, "coordinates": self.state_store.state.status(),
                "homing": self.homing.status(), **self.machine.status()}

    # ------------------------------------------------------------------ job life
    def _check_can_start(self, jog: AxisMotion | None = None) -> None:
        if self._job is not None or self._planning:
            busy = self._job.record.job_id if self._job is not None else "another submission"
            raise Refused("submit", f"busy: job {busy} is running (one job at a time)")
        if (refusal := self.machine.start_refusal(jog)) is not None:
            raise Refused("submit", refusal)
        if self.state() == "fault":
            raise Refused("submit", "the drives are in fault; send reset first")

    def _watch(self, job: ActiveJob) -> None:
        """Wait for the end of the job, then write its outcome (and the drives' recordings)."""
        assert job.handle is not None
        result = None
        while result is None:
            result = job.handle.wait(1.0)
            self.files.flush_feedback(job)
        job.plan.cancel()  # a streamed job's planner stops (the job ended)
        self.machine.end(job, result)
        status, settled = self.outcomes.settled_status()
        self.files.stop_feedback(job)  # after the settling: feedback.csv shows the axes come to rest
        outcome = self.outcomes.outcome(job, result, status, settled)
        self.files.stop_traffic()
        if self.simulation is not None:
            try:
                outcome["drive_recordings"] = self.simulation.write_recordings(str(job.record.drives_dir),
                                                                               self.link.cycle_slack)
            except OSError as err:
                log.warning(kv("recording_not_written", job=job.record.job_id, error=err))
        self.state_store.keep_program_state(job, outcome["outcome"])
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
            job.plan.release()  # what grows with the program, now (StreamedJob.release)

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


def check_homing(homing: Homing, status: MasterStatus, needs_homing: bool) -> None:
    """Refused when the job needs homing that is not done (``status``: its faults unhome axes)."""
    homing.forget_faulted(status.faults)
    why = homing.refusal(needs_homing)
    if why is not None:
        raise Refused("submit", why)


def held_position_mm(link: MotionLink, status: MasterStatus) -> np.ndarray:
    """Where the axes hold (their last set-points), machine mm."""
    held = np.array([[a.setpoint_counts for a in status.axes]])
    return link.axis_map.to_mm(held)[0]


def check_program_name(name: str) -> None:
    """A program name is a file name: it appears in every error line and names the record file."""
    if not name or len(name) > 255 or any(ord(ch) < 32 or ch == "\x7f" for ch in name):
        raise InputError("field 'name'", "must be a file name of 1-255 printable characters")


def axes_status(status: MasterStatus, axis_map: AxisMap, config: MachineConfig) -> list[dict[str, Any]]:
    """Each axis' drive state and positions in mm: AxisMap.to_mm's arithmetic on Python
    numbers (numpy's per-call overhead was a fifth of a status read for three axes)."""
    scale = zip(axis_map.offset_counts.tolist(), axis_map.sign.tolist(), axis_map.counts_per_mm.tolist())
    axes = []
    for i, (a, (offset, sign, per_mm)) in enumerate(zip(status.axes, scale)):
        actual = a.position_counts if a.position_counts is not None else a.setpoint_counts
        axes.append({"name": a.name, "node": a.node_id, "drive_state": a.state, "statusword": a.statusword,
                     "commanded_mm": round((a.setpoint_counts - offset) * sign / per_mm, 6),
                     "actual_mm": round((actual - offset) * sign / per_mm, 6),
                     "following_error_mm": None if a.following_error_counts is None else
                     round(a.following_error_counts * sign / per_mm, 6),
                     "emcy_count": a.emcy_count, "soft_limits_mm": _limits(config.axes[i].soft_limits_mm)})
    return axes


def cycles_status(status: MasterStatus) -> dict[str, Any]:
    """The status' ``cycles``: counted, late, missed, send errors, lateness p99 and max."""
    t = status.timing
    return {"count": t.cycles, "late": t.late_cycles, "missed": t.missed_cycles, "send_errors": t.send_errors,
            "lateness_p99_ms": round(t.lateness_p99_s * 1e3, 3), "lateness_max_ms": round(t.lateness_max_s * 1e3, 3)}


def slack_status(slack: CycleSlack | None) -> dict[str, Any]:
    """The status' ``cycles`` of the cycle thread's slack (fieldbus.cycle_slack): other threads'
    steps it ran, those that ended after its next wake-up, work taken back for want of slack."""
    if slack is None:
        return {"slack_steps": 0, "slack_overruns": 0, "slack_withdrawn": 0, "slack_overrun_places": {}}
    return {"slack_steps": slack.steps_run, "slack_overruns": slack.overruns, "slack_withdrawn": slack.withdrawn,
            "slack_overrun_places": dict(slack.overrun_places)}


def _limits(pair: tuple[float, float] | None) -> list[float] | None:
    return None if pair is None else [float(pair[0]), float(pair[1])]
