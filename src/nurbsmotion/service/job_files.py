"""A job's record folder (service.records) as the controller fills it: the program,
configuration and plan before any motion, a rejected program's errors, feedback.csv
(every TPDO1, service.feedback) and the bus traffic log while the job runs."""

from __future__ import annotations

import logging
import shutil

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.log import kv
from nurbsmotion.service.active_job import ActiveJob, JobPlan
from nurbsmotion.service.feedback import FeedbackLog
from nurbsmotion.service.motion import MotionLink
from nurbsmotion.service.program_file import ProgramFile
from nurbsmotion.service.record_config import config_dict
from nurbsmotion.service.records import TRAFFIC_FILE, JobRecord, JobRecords

log = logging.getLogger("nurbsmotion.service.controller")  # the controller's log lines, as before


class JobFiles:
    """Writes a job's record folder and its logs (records: the folders of DATA_DIR/jobs)."""

    def __init__(self, config: MachineConfig, link: MotionLink, records: JobRecords) -> None:
        self.config = config
        self.link = link
        self.records = records

    def record(self, name: str, text: str | ProgramFile, plan: JobPlan) -> JobRecord:
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

    def record_rejection(self, name: str, text: str | ProgramFile, err: InputError) -> None:
        """A rejected program leaves a record (program + error lines) and one log line."""
        errors = str(err).splitlines()
        job_id = "-"
        try:
            job_id = self.records.create_rejected(name, text, errors).job_id
        except OSError as os_err:
            log.warning(kv("rejection_not_recorded", name=name, error=os_err.strerror or os_err))
        log.info(kv("submit_rejected", name=name, record=job_id, errors=len(errors), first=errors[0]))

    def record_feedback(self, record: JobRecord) -> FeedbackLog | None:
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

    def stop_feedback(self, job: ActiveJob) -> None:
        if job.feedback is None:
            return
        self.link.record_feedback(None)
        try:
            job.feedback.close(max(job.start_cycle, 0), self.link.cycle_slack)
        except OSError as err:
            log.warning(kv("feedback_not_written", job=job.record.job_id, error=err.strerror or err))

    def flush_feedback(self, job: ActiveJob) -> None:
        if job.feedback is not None and job.start_cycle >= 0:
            try:  # formatted in the cycle thread's slack, written here (service.feedback)
                job.feedback.flush(job.start_cycle, self.link.cycle_slack)
            except OSError as err:
                log.warning(kv("feedback_not_written", job=job.record.job_id, error=err.strerror or err))
                self.link.record_feedback(None)
                job.feedback = None

    def record_traffic(self, record: JobRecord) -> None:
        """monitoring.traffic_log: every bus frame of the job into its folder (log: candump,
        asc: Vector ASCII)."""
        fmt = self.config.monitoring.traffic_log
        if fmt != "none":
            self.link.record_traffic(str(record.folder / f"{TRAFFIC_FILE}.{fmt}"))

    def stop_traffic(self) -> None:
        if self.config.monitoring.traffic_log != "none":
            try:
                self.link.record_traffic(None)
            except FieldbusError as err:
                log.warning(kv("traffic_log_not_closed", error=err))

