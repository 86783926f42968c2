"""The machine's persisted state between jobs (offsets and tool, service.machine_state): the
offsets command changes it, a completed program's end state becomes it; DATA_DIR/offsets.json
is written at each change."""

from __future__ import annotations

import logging

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.service.active_job import ActiveJob
from nurbsmotion.service.machine_state import MachineState, save_state

log = logging.getLogger("nurbsmotion.service.controller")  # the controller's log lines, as before


class MachineStateStore:
    """The offsets and tool in force, and offsets.json that keeps them."""

    def __init__(self, config: MachineConfig, state: MachineState) -> None:
        self.config = config
        self.state = state  # offsets and tool: persisted after each completed job

    def persist(self, state: MachineState, reason: str) -> None:
        """Keep ``state`` and write it to DATA_DIR/offsets.json (InputError naming data_dir if it cannot)."""
        try:
            save_state(self.config.data_dir, state)
        except OSError as err:
            raise InputError("data_dir", f"cannot write the offsets in {self.config.data_dir}: "
                             f"{err.strerror or err}") from None
        self.state = state
        log.info(kv("offsets_saved", reason=reason, active=state.coordinates.active_name, tool=state.tool_in_spindle))

    def keep_program_state(self, job: ActiveJob, outcome: str) -> None:
        """A completed program's final offsets and tool become the machine's (offsets.json).
        A job that ended early keeps the state it started from: the reader's end state
        includes G10/G92 lines the machine never reached."""
        program = job.plan.program
        if outcome != "completed" or program is None or program.coordinates is None:
            return
        tool = program.tool_at_end if program.tool_at_end is not None else self.state.tool_in_spindle
        state = MachineState(program.coordinates, tool)
        if state == self.state:
            return
        try:
            self.persist(state, f"job {job.record.job_id} completed")
        except InputError as err:
            log.error(kv("offsets_not_saved", job=job.record.job_id, error=err))

