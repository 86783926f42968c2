"""SimNetwork: drives for a machine configuration, fault routing, recordings."""

from __future__ import annotations

import os
import threading
from pathlib import Path
from types import SimpleNamespace

import can
import pytest

from nurbsmotion.can.cia402 import NmtState
from nurbsmotion.errors import InputError
from nurbsmotion.sim import FaultInjection, SimNetwork
from nurbsmotion.sim.timing import MissingSetpoint, SyncSettings
from nurbsmotion.sim.network import DriveSetupError
from tests.helpers import wait_for


def machine(channel: str, eds: str | None = None) -> SimpleNamespace:
    axis = SimpleNamespace(name="X", node_id=4, mode="ip", eds=eds, identity=SimpleNamespace(vendor_id=7, product_code=8))
    return SimpleNamespace(bus=SimpleNamespace(interface="virtual", channel=channel, bitrate=1_000_000),
                           cycle_period_s=0.004, axes=[axis])


def test_for_machine_builds_each_axis_drive_out_of_the_box(channel: str) -> None:
    sync = SyncSettings(missing_setpoint=MissingSetpoint.EXTRAPOLATE, loss_periods=3)
    net = SimNetwork.for_machine(machine(channel), lag_cycles=3, max_velocity_counts_s=1234.0, sync=sync)
    drive = net[4]
    assert (net.interface, net.channel) == ("virtual", channel)
    with net:
        # nothing the master must write is pre-stored: mode and cycle are the EDS defaults
        assert drive.axis.mode_display == 8 and drive.period_s == pytest.approx(0.001)
        assert drive.value(0x1006) == 1000 and (drive.value(0x60C2, 1), drive.value(0x60C2, 2)) == (1, -3)
        assert drive.servo.lag_cycles == 3 and drive.servo.max_velocity_counts_s == 1234.0
        assert drive.value(0x1018, 1) == 7 and drive.sync_settings == sync


def test_for_machine_names_the_axis_whose_eds_does_not_load(channel: str, tmp_path: Path) -> None:
    with pytest.raises(DriveSetupError) as err:
        SimNetwork.for_machine(machine(channel, eds=str(tmp_path / "missing.eds")))
    assert err.value.axis_index == 0 and "axis X" in err.value.message


def test_inject_to_an_unknown_node_is_an_input_error(channel: str) -> None:
    net = SimNetwork(channel=channel)
    net.add_drive(1)
    with pytest.raises(InputError, match="node 5"):
        net.inject(FaultInjection("fault", node_id=5))
    with pytest.raises(ValueError):
        net.add_drive(1)


def test_write_recordings_one_file_per_drive(channel: str, tmp_path: Path) -> None:
    net = SimNetwork(channel=channel)
    for node_id in (3, 1):
        net.add_drive(node_id)
    paths = net.write_recordings(tmp_path / "rec")
    assert [p.name for p in paths] == ["node1.csv", "node3.csv"]
    paths = net.write_recordings(tmp_path / "rec", timelines=True)
    assert [p.name for p in paths] == ["node1.csv", "node1.sync.csv", "node3.csv", "node3.sync.csv"]


def _policy_of(thread: threading.Thread) -> int:
    assert thread.native_id is not None
    return os.sched_getscheduler(thread.native_id)


def _notifier_thread(channel: str) -> threading.Thread:
    """python-can names its receive thread after the notifier's class and the bus
    (``BatchNotifier for bus "Virtual bus channel <channel>"``)."""
    return next(t for t in threading.enumerate() if "Notifier for bus" in t.name and channel in t.name)


def _stop_node_1(net: SimNetwork, master: can.BusABC) -> None:
    """NMT stop node 1 and wait (5 s at most) until the drive's receive thread handled it."""
    master.send(can.Message(arbitration_id=0x000, is_extended_id=False, data=bytes([0x02, 1])))
    wait_for(lambda: net[1].nmt_state == NmtState.STOPPED, 5.0, "node 1 in NMT STOPPED", 0.005)
    assert net[1].nmt_state == NmtState.STOPPED


def test_rt_priority_runs_the_receive_and_ticker_threads_as_it_reports(channel: str) -> None:
    """The daemon's simulated drives (service.link) stand in for drives with their own CPU:
    the receive thread (from its start) and the ticker take the SCHED_FIFO priority asked,
    where the process may (root / CAP_SYS_NICE); the policy each reports is the one in force."""
    net = SimNetwork(channel=channel)
    net.add_drive(1)
    net.rt_priority = 17
    with net, can.Bus(interface="virtual", channel=channel) as master:
        _stop_node_1(net, master)
        wait_for(lambda: "ticker" in net.thread_policy, 5.0, "the ticker's thread policy", 0.005)
        assert set(net.thread_policy) == {"receive", "ticker"}
        assert net._ticker is not None
        for name, thread in (("receive", _notifier_thread(channel)), ("ticker", net._ticker)):
            fifo = net.thread_policy[name] == "SCHED_FIFO"
            assert fifo or net.thread_policy[name].startswith("normal: ")
            assert (_policy_of(thread) == os.SCHED_FIFO) == fifo
            if fifo:
                assert os.sched_getparam(thread.native_id).sched_priority == 17


def test_without_rt_priority_the_threads_keep_the_normal_policy(channel: str) -> None:
    net = SimNetwork(channel=channel)
    net.add_drive(1)
    with net, can.Bus(interface="virtual", channel=channel) as master:
        _stop_node_1(net, master)  # the receive thread has handled a frame
        assert net.thread_policy == {} and net._ticker is not None
        assert _policy_of(net._ticker) == _policy_of(_notifier_thread(channel)) == os.SCHED_OTHER
