"""The csv spindle's 0x60FF in its RPDO with every SYNC through the kernel queue on a real
vcan0: the master (this process, kernel-queue writer: the frames are packed into the BCM ring
ahead of time) and the spindle's bring-up (RPDO1 = 0x60FF by canopen's PdoMap), the drives
and the spindle simulated in this process on their own vcan0 socket (in a separate `sim`
process inside User-Mode Linux they applied its SDO writes up to 13 s late on a loaded host, as
test_spindle_on_vcan found), an independent listener on the wire: one 0x60FF per SYNC,
ramped by at most one step per cycle up and down."""

from __future__ import annotations

import struct
import time

import pytest
import yaml

from nurbsmotion.config import load_config
from nurbsmotion.fieldbus import Master
from nurbsmotion.fieldbus.spindle import SpindleDrive
from nurbsmotion.sim import SimNetwork
from tests.vcan.conftest import CYCLE_PERIOD_S
from tests.vcan.test_kernel_queue import WireListener
from tests.vcan.two_processes import SLOW_KERNEL_MASTER_OPTIONS, write_vcan_config

# quarantined 2026-11-24 21:50: failed 6 of 6 runs on main, the machine2 tip and the commit that
# added it (quiet host, load < 1): the spindle's SDO answers (0x6502, 0x1600 mapping, statusword)
# took over 10 s from the simulated drives in this process inside UML (docs/vcan.md, Still to do)
pytestmark = [pytest.mark.vcan, pytest.mark.quarantine]

SPINDLE_NODE = 5
ACCEL_RPM_S = 10000
STEP_COUNTS_S = ACCEL_RPM_S * 4096 / 60 * CYCLE_PERIOD_S


def test_csv_spindle_velocity_rides_every_sync_in_the_kernel_queue(vcan0, tmp_path):
    path = write_vcan_config(tmp_path, vcan0)
    raw = yaml.safe_load(path.read_text())
    raw["spindle"] = {"node_id": SPINDLE_NODE, "mode": "csv", "counts_per_rev": 4096, "max_rpm": 6000,
                      "accel_rpm_s": ACCEL_RPM_S, "at_speed_timeout_s": 20.0}
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    config = load_config(path)
    sim = SimNetwork.for_machine(config, record=False).start()  # this process: the guest's one CPU
    listener = WireListener(vcan0)
    listener.bus.set_filters([{"can_id": 0x80, "can_mask": 0x7FF}, {"can_id": 0x205, "can_mask": 0x7FF}])
    try:
        with Master(config, sync_source="kernel", **SLOW_KERNEL_MASTER_OPTIONS) as master:
            master.bring_up()
            master.receive_from(SPINDLE_NODE)
            assert master.network is not None and master.cyclic_velocity is not None
            spindle = SpindleDrive(master.network, config.spindle, cycle_period_s=config.cycle_period_s,
                                   sdo_timeout_s=10.0, cyclic=master.cyclic_velocity)
            spindle.bring_up()
            try:
                spindle.command_rpm(3000)
                assert spindle.wait_at_speed(30.0), spindle.status()
                spindle.command_rpm(0)
                deadline = time.monotonic() + 30.0
                while master.cyclic_velocity.value_at(master.status().timing.cycles) != 0:
                    assert time.monotonic() < deadline
                    time.sleep(0.05)
                time.sleep(0.3)
            finally:
                spindle.close()
    finally:
        listener.stop()
        sim.stop()
    velocity, syncs = [], 0
    for _, can_id, data in listener.frames:
        if can_id == 0x80:
            syncs += 1
        else:
            velocity.append(struct.unpack("<i", data)[0])
    target = round(3000 * 4096 / 60)
    assert max(velocity) == target and velocity[-1] == 0
    steps = [b - a for a, b in zip(velocity, velocity[1:])]
    assert max(abs(s) for s in steps) <= STEP_COUNTS_S + 1, "a jump in 0x60FF"
    assert abs(len(velocity) - syncs) <= 2, f"{len(velocity)} 0x60FF frames for {syncs} SYNCs"
