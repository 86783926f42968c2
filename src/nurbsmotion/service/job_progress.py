"""A running job's progress as the status shows it: set-point reached of how many, percent,
feed, the program line, a pause's reason (from the master's status and the job's plan)."""

from __future__ import annotations

import time
from typing import Any

from nurbsmotion.fieldbus.reports import MasterStatus
from nurbsmotion.service.active_job import ActiveJob
from nurbsmotion.service.start_line import resume_of


def job_progress(job: ActiveJob | None, status: MasterStatus, effective_rate: float) -> dict[str, Any] | None:
    """The status' ``job``; ``effective_rate``: the feed override in effect for the job."""
    if job is None:
        return None
    total = job.plan.total_cycles  # None while a streamed job is still being planned
    mine = status.job_index is not None and (total is None and job.start_cycle >= 0 or status.job_length == total)
    index = status.job_index if mine and status.job_index is not None else ended_index(job)
    cycle = max(index + 1, 0)
    rate = status.rate if status.rate is not None else effective_rate  # 0 while held
    feed = job.plan.feed_at(index) * rate
    reached = line_reached(job, index)
    pause = job.plan.pauses[status.pause] if status.pause is not None else None
    return {"paused": pause.reason if pause else None, "tool": pause.tool if pause else None,"id": job.record.job_id, "name": job.name, "folder": str(job.record.folder), "cycle": cycle,
            "total": total if total is not None else max(status.job_length or 0, cycle),
            "percent": round(job.plan.percent_at(index), 2), "planned_all": total is not None,
            "feed_mm_s": round(feed, 3),
            "override_percent": round(effective_rate * 100.0, 3),
            "line": reached["where"] if reached else None, "started_at": job.started_at,
            "start_line": getattr(resume_of(job.plan.program), "line", None),
            "elapsed_s": round(time.monotonic() - job.started_s, 3)}


def ended_index(job: ActiveJob) -> int:
    """The last planned set-point sent of a job the master has let go of (it ended; its
    record is being written), so the progress shows where it stopped, not cycle 0; -1
    before it started."""
    result = getattr(job.handle, "result", None)
    return result.sent - 1 if result is not None else -1


def pause_reason(job: ActiveJob, status: MasterStatus) -> str | None:
    return job.plan.pauses[status.pause].reason if status.pause is not None else None


def line_reached(job: ActiveJob, index: int) -> dict[str, Any] | None:
    """The program line of planned set-point ``index`` (None before the first one)."""
    program, block = job.plan.program, job.plan.block_at(index)
    if program is None or block is None or not program.blocks:  # no motion: no line reached
        return None
    source = program.blocks[block].source
    return {"where": str(source), "line": source.line, "text": source.text, "block": block, "setpoint": index}
