"""The master and the simulated drives in two processes on a real kernel vcan0: what users
run (`nurbsmotion sim --config` next to the controller). Every streamed set-point must be
applied by its drive exactly once, in order."""

from __future__ import annotations

import numpy as np
import pytest

from tests.vcan.two_processes import (AXES, assert_applied_once_in_order, retrying_a_stuck_bring_up, run_job,
                                      write_vcan_config)

pytestmark = pytest.mark.vcan

JOB_CYCLES = 300  # 1.2 s at 4 ms


def test_master_streams_to_simulated_drives_in_another_process_on_vcan0(vcan0, tmp_path, sim_process):
    config_path = write_vcan_config(tmp_path, vcan0)
    sim = sim_process(config_path)
    run = retrying_a_stuck_bring_up(lambda attempt: run_job(config_path, sim, JOB_CYCLES))

    assert run.result is not None, f"job not finished; {run.diagnosis()}"
    assert run.result.outcome == "done", f"{run.result}; {run.diagnosis()}"
    for j, (name, node_id, _, _) in enumerate(AXES):
        assert_applied_once_in_order(run.sim.applied_setpoints(node_id), run.rows[:, j].astype(np.int64),
                                     run.held_counts[j], f"{name} ({run.diagnosis()})")
