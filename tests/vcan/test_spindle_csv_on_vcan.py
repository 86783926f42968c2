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

# Quarantined 2026-11-24 21:50 after 6 of 6 failed runs (the spindle's SDO answers from the
# simulated drives in this process took over 10 s inside UML); out of quarantine since
# 2026-11-25, when master and drives here read their frames in batches (socketcan_batch.
# BatchNotifier: a lock and a clock read per wake-up, not per frame): docs/vcan.md.
pytestmark = [pytest.mark.vcan]

SPINDLE_NODE = 5
ACCEL_RPM_S = 10000
STEP_COUNTS_S = ACCEL_RPM_S * 4096 / 60 * CYCLE_PERIOD_S


def _stopped_on_the_wire(frames: list[tuple[float, int, bytes]]) -> bool:
    """The listener saw 0x60FF reach the target and then 0 (the spindle's RPDO1)."""
    seen_target = False
    for _, can_id, data in list(frames):
        if can_id == 0x200 + SPINDLE_NODE:
            value = struct.unpack("<i", data)[0]
            seen_target = seen_target or value == round(3000 * 4096 / 60)
            if seen_target and value == 0:
                return True
    return False


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
                # until the wire shows the ramp down ended (the master's cycle count is its own
                # belief; inside a starved guest the listener and the kernel lag it)
                deadline = time.monotonic() + 30.0
                while not _stopped_on_the_wire(listener.frames):
                    assert time.monotonic() < deadline, "0x60FF never back to 0 on the wire"
                    time.sleep(0.05)
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
