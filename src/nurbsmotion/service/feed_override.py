"""The feed override the operator requests (0-150 %), and what it is in effect for a job:
the requested rate capped by the plan's ``max_rate`` (service.rate.effective_rate), set on
the motion link, kept in the job's override history."""

from __future__ import annotations

import time
from typing import Any

from nurbsmotion.service.active_job import ActiveJob, JobPlan
from nurbsmotion.service.motion import MotionLink
from nurbsmotion.service.rate import effective_rate


class FeedOverride:
    """The requested override (a fraction, 1.0: 100 %) and the rate it sets on the link."""

    def __init__(self, link: MotionLink) -> None:
        self.link = link
        self.requested = 1.0  # requested, as a fraction

    def status(self, job: ActiveJob | None) -> dict[str, Any]:
        """The status' ``override``; ``max_percent`` None without a job (always there: a
        subscriber applying changes cannot tell a field that went away from one set to None)."""
        return {"requested_percent": round(self.requested * 100.0, 3),
                "effective_percent": round(self.effective(job) * 100.0, 3),
                "max_percent": round(max(1.0, job.plan.max_rate) * 100.0, 3) if job is not None else None}

    def effective(self, job: ActiveJob | None) -> float:
        return effective_rate(self.requested, job.plan.max_rate) if job is not None else self.requested

    def entry(self, job: ActiveJob, effective: float, by: str, index: int) -> dict[str, Any]:
        """One entry of the job's override history: when (seconds since the job started and
        the planned set-point reached), who, requested and effective percent."""
        return {"at_s": round(time.monotonic() - job.started_s, 3), "setpoint": index, "by": by,
                "requested_percent": round(self.requested * 100.0, 3),
                "effective_percent": round(effective * 100.0, 3)}

    def set_link_rate(self, plan: JobPlan) -> float:
        rate = effective_rate(self.requested, plan.max_rate)
        self.link.set_rate(rate)
        return rate
