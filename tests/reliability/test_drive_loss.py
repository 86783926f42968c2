"""Through the daemon (in-process, so the test can cut a simulated drive's power): a drive
lost mid-job is detected within three heartbeat periods, every axis stops, the job record
names the fault; reset is refused with the node named while the drive is off and brings
every drive up again once it is back; then a new job runs. Also a few fault kinds injected
over the control API end in a job record that names them, with no set-point jump."""

from __future__ import annotations

import tempfile
import uuid
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.can.cia402 import State
from nurbsmotion.config import MachineConfig, parse_config
from nurbsmotion.service.client import Client
from nurbsmotion.service.daemon import Daemon
from nurbsmotion.fieldbus import Master
from nurbsmotion.service.link import SimulatedDrives
from nurbsmotion.sim import FaultInjection, read_csv
from tests.reliability.rig import (A_MAX_MM_S2, COUNTS_PER_MM, HEARTBEAT_CONSUMER_MS, HEARTBEAT_PRODUCER_MS,
                                   V_MAX_MM_S, assert_records_within_limits)
from tests.helpers import wait_for
from tests.integration.daemon_helpers import job_reached

LONG = "G21 G90\nG01 X60 Y20 Z5 F4800\n"  # ~1 s
SHORT = "G21 G90\nG01 X1 Y1 Z1 F3000\n"
PERIOD_MS = 4


def daemon_config(folder: Path) -> MachineConfig:
    axes = "".join(f"  - {{name: {n}, node_id: {i + 1}, mode: {m}, counts_per_mm: {COUNTS_PER_MM},"
                   f" soft_limits_mm: [-100, 100], max_velocity_mm_s: {V_MAX_MM_S}, max_accel_mm_s2: {A_MAX_MM_S2},"
                   f" following_error_window_mm: 2.0}}\n"
                   for i, (n, m) in enumerate((("X", "csp"), ("Y", "csp"), ("Z", "ip"))))
    text = (f"cycle_period_ms: {PERIOD_MS}\nsimulate: true\nbus: {{interface: virtual, channel: dl-{uuid.uuid4().hex}}}\n"
            f"interpolation: {{algorithm: wang, feed_mm_min: 3000, max_accel_mm_s2: 1000, acc_time_s: 0.1}}\n"
            f"monitoring: {{heartbeat_producer_ms: {HEARTBEAT_PRODUCER_MS}, heartbeat_consumer_ms:"
            f" {HEARTBEAT_CONSUMER_MS}}}\ncontrol: {{socket: {folder / 'ctl.sock'}}}\ndata_dir: {folder / 'data'}\n"
            f"axes:\n{axes}")
    return parse_config(text, "drive-loss.yaml")


def open_link_normal_priority(config: MachineConfig) -> tuple[Master, SimulatedDrives]:
    """service.link.open_link without SCHED_FIFO: in-process drives on 2 loaded cores would
    otherwise be starved into false heartbeat losses (the daemon proper runs them the same)."""
    simulation = SimulatedDrives(config).start()
    master = Master(config, rt_priority=None)
    master.bring_up()
    return master, simulation


class Running:
    def __init__(self) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix="nm-dl-"))  # short: AF_UNIX path limit
        self.config = daemon_config(self.folder)
        self.daemon = Daemon(self.config, open_motion=open_link_normal_priority)

    def ask(self, cmd: str, **fields) -> dict:
        with Client(self.config.control.socket, timeout_s=30.0) as client:
            return client.request(cmd, **fields)

    def drive(self, node: int):
        assert self.daemon.simulation is not None
        return self.daemon.simulation.network[node]  # type: ignore[attr-defined]

    def cycle(self) -> int:
        assert self.daemon.controller is not None
        return self.daemon.controller.link.status().cycle

    def submit_and_reach(self, program: str, fraction: float) -> str:
        response = self.ask("submit", name="part.nc", program=program)
        assert response["ok"], response
        wait_for(lambda: job_reached(self.ask("status"), fraction), what=f"{fraction:.0%} of the job")
        return response["job"]["id"]

    def outcome(self, job_id: str) -> dict:
        return wait_for(lambda: self.ask("job", id=job_id)["job"]["outcome"], what="the job record's outcome")

    def recordings(self, job_id: str) -> dict[int, np.ndarray]:
        folder = Path(self.ask("job", id=job_id)["job"]["folder"]) / "drives"
        return {n: np.array([[r.sync_index, r.mode, r.setpoint_counts, r.position_actual_counts, r.sync_counter]
                             for r in read_csv(folder / f"node{n}.csv")], dtype=np.int64).reshape(-1, 5)
                for n in (1, 2, 3)}


@pytest.fixture
def running():
    r = Running()
    r.daemon.start()
    try:
        yield r
    finally:
        r.daemon.close()


def test_a_drive_lost_mid_job_is_detected_stops_everything_and_comes_back_after_reset(running):
    r = running
    job_id = r.submit_and_reach(LONG, 0.3)
    lost_at = r.cycle()
    r.drive(2).inject(FaultInjection("power_loss"))
    wait_for(lambda: r.ask("status")["state"] == "fault", what="the loss to be seen")
    outcome = r.outcome(job_id)
    assert outcome["outcome"] == "fault" and outcome["fault"]["node"] == 2, outcome
    assert outcome["fault"]["kind"] in ("heartbeat", "following_error") and "node 2" in outcome["reason"]
    detected_ms = (outcome["fault"]["cycle"] - lost_at) * PERIOD_MS
    assert detected_ms <= 3 * HEARTBEAT_PRODUCER_MS, f"detected {detected_ms} ms after the loss"
    assert 0 < outcome["sent"] < outcome["planned"]
    wait_for(lambda: r.ask("status")["phase"] == "disabled", what="every axis stopped")
    assert r.drive(1).state is not State.OPERATION_ENABLED and r.drive(3).state is not State.OPERATION_ENABLED
    assert_records_within_limits(r.recordings(job_id), PERIOD_MS / 1000)

    refused = r.ask("reset")  # the drive is still off: refused, naming it, and the daemon keeps serving
    assert refused["ok"] is False and refused["error"].startswith("reset: node 2: bring-up step 'boot-up'")
    assert r.ask("status")["state"] == "fault"

    r.drive(2).power_on()
    assert r.ask("reset")["ok"] is True
    status = r.ask("status")
    assert status["state"] == "idle" and all(a["drive_state"] == "OPERATION ENABLED" for a in status["axes"])
    again = r.ask("submit", name="again.nc", program=SHORT)
    assert again["ok"], again
    final = r.outcome(again["job"]["id"])
    assert final["outcome"] == "completed", final


@pytest.mark.parametrize("spec, kinds", [
    ("node=3,kind=following_error", {"following_error", "emcy"}),
    ("node=1,kind=ignore_sync,count=100", {"following_error"}),  # 400 ms: longer than the consumer time
    ("node=2,kind=drop_rpdo,count=100", {"following_error"}),
    ("node=2,kind=fault,code=0x5530", {"emcy", "fault_bit"}),
])
def test_a_fault_injected_over_the_api_is_named_in_the_job_record(running, spec, kinds):
    r = running
    node = int(spec.split(",")[0].split("=")[1])
    job_id = r.submit_and_reach(LONG, 0.25)
    assert r.ask("inject_fault", spec=spec)["ok"]
    outcome = r.outcome(job_id)
    assert outcome["outcome"] == "fault" and outcome["fault"]["node"] == node, outcome
    assert {f["kind"] for f in outcome["faults"] if f["node"] == node} & kinds, outcome["faults"]
    assert outcome["reason"] == outcome["fault"]["message"] and "\n" not in outcome["reason"]
    assert_records_within_limits(r.recordings(job_id), PERIOD_MS / 1000)
    wait_for(lambda: r.ask("status")["phase"] in ("disabled", "holding"), what="the axes to stop")
    stats = r.drive(node).stats  # a count-limited injection must have run out, as an operator would wait
    wait_for(lambda: stats.syncs_ignored in (0, 100) and stats.rpdos_dropped in (0, 100), what="the injection to end")
    assert r.ask("reset")["ok"] is True
    again = r.ask("submit", name="again.nc", program="G21 G90\nG01 X0 Y0 Z0 F3000\n")
    assert again["ok"], again
    final = r.outcome(again["job"]["id"])
    assert final["outcome"] == "completed", final
