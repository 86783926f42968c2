"""The master's side of the spindle drive against the simulated drive on python-can's virtual
bus: bring-up in profile velocity (3) and cyclic synchronous velocity (9) mode, 'at speed'
from bit 10 / the ramp, direction, stop, quick stop + disable without a fault report, a fault."""

from __future__ import annotations

import contextlib
import functools
import uuid
from collections.abc import Iterator
from dataclasses import replace

import canopen
import pytest

from nurbsmotion.can import drive_od
from nurbsmotion.config import default_eds_path
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.spindle import SpindleDrive, csv_at_speed, ramp_step
from nurbsmotion.sim.network import SimNetwork, SpindleSim
from nurbsmotion.config.spindle import SpindleConfig, SpindleMode
from tests.helpers import wait_for as _wait_for

wait_for = functools.partial(_wait_for, timeout_s=3.0, poll_s=0.005)  # this module's waits

NODE = 5
CONFIG = SpindleConfig(node_id=NODE, counts_per_rev=4096, max_rpm=12000, accel_rpm_s=30000,
                       od=drive_od.load_description(default_eds_path(), NODE))
SYNC_S = 0.002


@contextlib.contextmanager
def spindle_bus(config: SpindleConfig) -> Iterator[tuple[canopen.Network, SimNetwork]]:
    channel = f"spindle-{uuid.uuid4().hex}"
    sim = SimNetwork(channel=channel)
    sim.add_spindle(SpindleSim(NODE, config.counts_per_rev), record=False)
    sim.start()
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(interface="virtual", channel=channel)
    master.sync.start(SYNC_S)  # the drive's velocity loop runs on SYNC
    try:
        yield master, sim
    finally:
        master.sync.stop()
        master.disconnect()
        sim.stop()


def test_ramp_step_and_csv_window():
    assert ramp_step(0.0, 100.0, 30.0) == 30.0 and ramp_step(90.0, 100.0, 30.0) == 100.0
    assert ramp_step(0.0, -100.0, 30.0) == -30.0
    assert csv_at_speed(9810, 10000) and not csv_at_speed(9790, 10000) and csv_at_speed(1, 0)


@pytest.mark.parametrize("mode", list(SpindleMode))
def test_spins_up_to_speed_both_directions_and_stops(mode):
    config = replace(CONFIG, mode=mode)
    with spindle_bus(config) as (master, sim):
        spindle = SpindleDrive(master, config)
        spindle.bring_up()
        try:
            assert sim[NODE].axis.mode_display == mode.number
            spindle.command_rpm(6000)  # 0.2 s ramp at 30000 rpm/s
            assert not spindle.at_speed()
            assert spindle.wait_at_speed(3.0)
            assert spindle.status().actual_rpm == pytest.approx(6000, rel=0.021)
            assert sim[NODE].axis.velocity_actual > 0
            spindle.command_rpm(-3000)  # M4: the other way
            assert spindle.wait_at_speed(3.0)
            assert sim[NODE].axis.velocity_actual < 0
            spindle.command_rpm(0)
            assert wait_for(lambda: sim[NODE].axis.velocity_actual == 0)
            assert spindle.status().fault is None
        finally:
            spindle.close()


def test_quick_stop_and_disable_are_no_fault_and_enable_comes_back():
    faults: list[str] = []
    with spindle_bus(CONFIG) as (master, sim):
        spindle = SpindleDrive(master, CONFIG, on_fault=faults.append)
        spindle.bring_up()
        try:
            spindle.command_rpm(3000)
            assert spindle.wait_at_speed(3.0)
            spindle.quick_stop()
            spindle.disable()
            assert sim[NODE].axis.velocity_actual == 0  # the quick-stop ramp ended before the disable
            assert wait_for(lambda: spindle.status().state == "SWITCH ON DISABLED")
            assert not spindle.enabled and faults == []
            spindle.enable()
            assert spindle.enabled and spindle.status().commanded_rpm == 0
        finally:
            spindle.close()


def test_a_drive_that_leaves_operation_enabled_is_reported_once():
    faults: list[str] = []
    with spindle_bus(CONFIG) as (master, sim):
        spindle = SpindleDrive(master, CONFIG, on_fault=faults.append)
        spindle.bring_up()
        try:
            spindle.command_rpm(3000)
            master[NODE].sdo[0x6040].raw = 0x02  # someone else quick-stops it
            assert wait_for(lambda: bool(faults))
            assert len(faults) == 1 and "left OPERATION ENABLED" in faults[0]
            assert not spindle.wait_at_speed(0.2)
        finally:
            spindle.close()


def test_no_answer_names_node_and_step():
    with spindle_bus(replace(CONFIG, node_id=9, od=drive_od.load_description(default_eds_path(), 9))) as (master, _):
        spindle = SpindleDrive(master, replace(CONFIG, node_id=9, od=drive_od.load_description(default_eds_path(), 9)))
        with pytest.raises(FieldbusError, match=r"node 9: spindle step 'read 0x6502': no SDO answer"):
            spindle.bring_up()


def test_the_drive_is_told_to_watch_the_masters_heartbeat_and_the_cycle_period():
    with spindle_bus(CONFIG) as (master, sim):
        spindle = SpindleDrive(master, CONFIG, master_heartbeat=(127, 500), cycle_period_s=SYNC_S)
        spindle.bring_up()
        try:
            assert master[NODE].sdo[0x1016][1].raw == 127 << 16 | 500
            assert sim[NODE].period_s == pytest.approx(SYNC_S)  # 0x60C2: the ramp steps by the SYNC period
        finally:
            spindle.close()


def test_a_late_answer_to_an_earlier_read_does_not_fail_the_next_write(caplog):
    """The vcan lane's spindle failure: a monitor read timed out, its answer came during the
    next request (a write of 0x60FF) and canopen took it as that write's answer ("Unexpected
    response 0x4B"). Here that answer arrives right after the write's request is sent: the
    client drops it (one log line) and takes the drive's own answer."""
    late_answer = bytes([0x4B, 0x41, 0x60, 0x00, 0x37, 0x06, 0x00, 0x00])  # 0x6041 = 0x0637, 2 bytes
    with spindle_bus(CONFIG) as (master, sim):
        spindle = SpindleDrive(master, CONFIG)
        spindle.bring_up()
        try:
            plain_send = master.send_message

            def send_message(can_id: int, data: bytes, remote: bool = False) -> None:
                plain_send(can_id, data, remote)
                if can_id == 0x600 + NODE and bytes(data[:3]) == b"\x23\xff\x60":  # initiate download of 0x60FF
                    spindle.node.sdo.on_response(0x580 + NODE, late_answer, 0.0)

            master.send_message = send_message  # type: ignore[method-assign]
            spindle.command_rpm(3000)
            assert spindle.wait_at_speed(3.0) and spindle.status().fault is None
        finally:
            spindle.close()
    assert any("sdo_answer_dropped node=5" in r.getMessage() for r in caplog.records)
