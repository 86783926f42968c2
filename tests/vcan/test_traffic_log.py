"""The master's traffic log (candump .log, Vector .asc) on a real kernel vcan0: every line
parses, each cycle is SYNC then one RPDO per axis, the RPDOs carry the streamed set-points,
and an independent listener on vcan0 (as `candump -L vcan0` would) heard the same frames."""

from __future__ import annotations

import time
from pathlib import Path

import can
import numpy as np
import pytest

from nurbsmotion.can import cia402 as c
from nurbsmotion.fieldbus.pdo import RPDO_FORMAT
from tests.vcan.two_processes import (AXES, JobRun, assert_applied_once_in_order, retrying_a_stuck_bring_up, run_job,
                                      write_vcan_config)

pytestmark = pytest.mark.vcan

JOB_CYCLES = 100
QUIET_S = 0.5  # the bus is quiet after shutdown: the listener has read everything
DRAIN_TIMEOUT_S = 10.0
NODES = [node for _, node, _, _ in AXES]
RPDO_IDS = [c.COB_RPDO[0] + node for node in NODES]
MASTER_IDS = {c.COB_NMT, c.COB_SYNC, *RPDO_IDS, *(c.COB_SDO_RX + node for node in NODES)}
CYCLE_IDS = [c.COB_SYNC, *RPDO_IDS]


def frames(messages: list[can.Message], ids: set[int] | None = None, exclude: set[int] | None = None) -> list[tuple]:
    """(id, data) of the messages whose id is in `ids` (or not in `exclude`), in order."""
    return [(m.arbitration_id, bytes(m.data)) for m in messages
            if (ids is None or m.arbitration_id in ids) and (exclude is None or m.arbitration_id not in exclude)]


def cycle_frames(messages: list[can.Message]) -> list[tuple]:
    return frames(messages, set(CYCLE_IDS))


class LastHeard(can.Listener):
    """When the last frame was read (time.monotonic)."""

    def __init__(self) -> None:
        self.at_s = time.monotonic()

    def on_message_received(self, msg: can.Message) -> None:
        self.at_s = time.monotonic()


def wait_quiet(last: LastHeard) -> None:
    deadline = time.monotonic() + DRAIN_TIMEOUT_S
    while time.monotonic() - last.at_s < QUIET_S and time.monotonic() < deadline:
        time.sleep(QUIET_S / 5)


def first_run_of(part: list[tuple], whole: list[tuple]) -> int | None:
    """Index where `part` occurs in `whole` as a contiguous run, or None."""
    for start in range(len(whole) - len(part) + 1):
        if whole[start:start + len(part)] == part:
            return start
    return None


def rpdo_setpoints(cycle: list[tuple], node: int) -> np.ndarray:
    return np.array([RPDO_FORMAT.unpack(data)[1] for can_id, data in cycle if can_id == c.COB_RPDO[0] + node],
                    dtype=np.int64)


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_the_traffic_log_is_complete_and_agrees_with_the_bus(vcan0, tmp_path, sim_process, suffix):
    config_path = write_vcan_config(tmp_path, vcan0)
    sim = sim_process(config_path)

    def attempt(number: int) -> tuple[JobRun, Path, Path, float, float]:
        log_path, witness_path = tmp_path / f"traffic{number}{suffix}", tmp_path / f"witness{number}.log"
        started_s = time.time()
        with can.Bus(interface="socketcan", channel=vcan0) as witness_bus:
            last = LastHeard()
            witness = can.Notifier(witness_bus, [can.Logger(str(witness_path)), last], timeout=0.1)
            try:
                run = run_job(config_path, sim, JOB_CYCLES, traffic_log=str(log_path))
                wait_quiet(last)
            finally:
                witness.stop(5.0)
        return run, log_path, witness_path, started_s, time.time()

    run, log_path, witness_path, started_s, ended_s = retrying_a_stuck_bring_up(attempt)
    assert run.result is not None and run.result.outcome == "done", f"{run.result}; {run.diagnosis()}"

    logged = list(can.LogReader(str(log_path)))  # raises on a line it cannot parse
    heard = list(can.LogReader(str(witness_path)))
    if suffix == ".log":
        assert len(logged) == len(Path(log_path).read_text().splitlines())
        assert all(started_s <= m.timestamp <= ended_s for m in logged)

    cycle = cycle_frames(logged)
    assert len(cycle) % len(CYCLE_IDS) == 0 and len(cycle) >= len(CYCLE_IDS) * JOB_CYCLES
    assert [can_id for can_id, _ in cycle] == CYCLE_IDS * (len(cycle) // len(CYCLE_IDS)), \
        "every cycle must be SYNC then one RPDO per axis, in node order"
    for j, (name, node, _, _) in enumerate(AXES):
        assert_applied_once_in_order(rpdo_setpoints(cycle, node), run.rows[:, j].astype(np.int64),
                                     run.held_counts[j], f"{name} in the traffic log")

    assert frames(logged, MASTER_IDS) == frames(heard, MASTER_IDS), "the master's frames on the bus"
    # The listener ran longer than the master's log: before it only the drives' heartbeats,
    # after it their last TPDOs and heartbeats. In between, the very same frames.
    from_drives, heard_from_drives = frames(logged, exclude=MASTER_IDS), frames(heard, exclude=MASTER_IDS)
    start = first_run_of(from_drives, heard_from_drives)
    assert start is not None, "the drives' frames in the traffic log are not those on the bus"
    assert all(c.COB_HEARTBEAT < can_id <= c.COB_HEARTBEAT + 127 for can_id, _ in heard_from_drives[:start])
