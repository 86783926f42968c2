"""The job the daemon runs: its record, plan, master handle and what happened to it so far
(service.controller starts it, its watcher ends it)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

from nurbsmotion.errors import Refused
from nurbsmotion.service.feedback import FeedbackLog
from nurbsmotion.service.job_common import PlannedJob
from nurbsmotion.service.job_events import JobEvents
from nurbsmotion.service.motion import JobHandle
from nurbsmotion.service.records import JobRecord, now_iso
from nurbsmotion.service.streamed_job import StreamedJob

JobPlan = PlannedJob | StreamedJob  # planned whole before motion, or while it runs (the daemon's lookahead jobs)


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


def running_job(job: ActiveJob | None, what: str) -> ActiveJob:
    """``job`` if it runs (the master has it), else Refused naming the request ``what``."""
    if job is None or job.handle is None:
        raise Refused(what, "no job is running")
    return job
