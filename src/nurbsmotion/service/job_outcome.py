"""How a job ended, as its record's outcome.json and the status show it: the outcome and its
reason, its faults (CiA-301 EMCY codes, following error in mm, job-relative cycles), the
line reached, and where the axes came to rest."""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.fieldbus.reports import FaultReport, JobResult, MasterStatus
from nurbsmotion.log import kv
from nurbsmotion.service.active_job import ActiveJob
from nurbsmotion.service.job_progress import line_reached
from nurbsmotion.service.jog import LEASE_REASON
from nurbsmotion.service.motion import MotionLink
from nurbsmotion.service.records import now_iso
from nurbsmotion.service.start_line import resume_of

log = logging.getLogger("nurbsmotion.service.controller")  # the controller's log lines, as before

SETTLE_S = 0.5  # the longest a job's end waits for the axes to reach their last set-point (final_position)
OUTCOME_OF_RESULT = {"done": "completed", "stopped": "stopped", "aborted": "aborted", "faulted": "fault"}


class JobOutcome:
    """A job's outcome and its faults, with the axes' scales from the configuration."""

    def __init__(self, config: MachineConfig, link: MotionLink) -> None:
        self.config = config
        self.link = link

    def settled_status(self) -> tuple[MasterStatus, bool]:
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

    def outcome(self, job: ActiveJob, result: JobResult, status: MasterStatus, settled: bool) -> dict[str, Any]:
        outcome = OUTCOME_OF_RESULT.get(result.outcome, "fault")
        if result.faults:
            outcome = "fault"
        faults = [self.fault_record(f, status, job.start_cycle) for f in result.faults]
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
                "line_reached": line_reached(job, result.sent - 1),
                "final_position": self.positions_mm(status), "settled": settled,
                "overrides": job.overrides, "machine_events": job.events.done if job.events is not None else [],
                "feedback_rows": job.feedback.rows if job.feedback is not None else None,
                "motion_time_s": round(time.monotonic() - job.started_s, 3),
                "missed_cycles": result.missed_cycles - job.missed_before,
                "late_cycles": result.late_cycles - job.late_before,
                "start_cycle": job.start_cycle, "started_at": job.started_at, "ended_at": now_iso()}

    def positions_mm(self, status: MasterStatus) -> dict[str, dict[str, float | None]]:
        """Per axis: the last set-point sent and the drive's position actual (TPDO1), in mm."""
        axis_map = self.link.axis_map
        commanded = axis_map.to_mm(np.array([[a.setpoint_counts for a in status.axes]]))[0]
        actual = axis_map.to_mm(np.array([[a.position_counts or 0 for a in status.axes]]))[0]
        return {a.name: {"commanded_mm": round(float(commanded[i]), 6),
                         "actual_mm": None if a.position_counts is None else round(float(actual[i]), 6)}
                for i, a in enumerate(status.axes)}

    def fault_record(self, fault: FaultReport, status: MasterStatus, start_cycle: int | None = None) -> dict[str, Any]:
        """fault_record() with the axis' scale and last EMCY code from the status."""
        axis = next((a for a in status.axes if a.node_id == fault.node_id), None)
        config = next((a for a in self.config.axes if a.node_id == fault.node_id), None)
        mm_per_count = None if config is None else (-1.0 if config.invert else 1.0) / config.counts_per_mm
        return fault_record(fault, start_cycle, mm_per_count, axis.last_emcy_code if axis else None,
                            axis.statusword if axis else None)



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
