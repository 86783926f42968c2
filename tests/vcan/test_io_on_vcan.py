"""The CiA-401 I/O node and the master's IoNode on a real kernel SocketCAN vcan0: bring-up by
SDO and canopen's PdoMap, heartbeat by the kernel's broadcast manager (python-can
send_periodic on socketcan), e-stop in TPDO1, outputs by RPDO1."""

from __future__ import annotations

import functools


import canopen
import pytest

from nurbsmotion.fieldbus.io import IoNode
from nurbsmotion.config.io import IoConfig, IoSignal
from nurbsmotion.sim.io_node import SimIoNode
from tests.helpers import wait_for as _wait_for

wait_for = functools.partial(_wait_for, timeout_s=3.0, poll_s=0.002)  # this module's waits

pytestmark = pytest.mark.vcan

IO = IoConfig(21, inputs=(IoSignal("estop", 0, active_low=True), IoSignal("limit_z_max", 5)),
              outputs=(IoSignal("coolant_flood", 0),))


def test_io_node_on_vcan0(vcan0: str) -> None:
    node_net, master = canopen.Network(), canopen.Network()
    for net in (node_net, master):
        net.NOTIFIER_CYCLE = 0.05
        net.connect(interface="socketcan", channel=vcan0)
    sim = SimIoNode(21, input_groups=1, output_groups=1)
    sim.set_input(0, True)  # e-stop contact closed
    heartbeats: list[bytes] = []
    master.subscribe(0x700 + 21, lambda can_id, data, ts: heartbeats.append(bytes(data)))
    try:
        sim.attach(node_net)
        changes: list[tuple[str, bool]] = []
        io = IoNode(master, IO, on_change=lambda name, active: changes.append((name, active)))
        io.bring_up(heartbeat_producer_ms=20)
        assert io.inputs == {"estop": False, "limit_z_max": False}
        wait_for(lambda: heartbeats[-1:] == [b"\x05"], what="OPERATIONAL heartbeat")
        sim.set_input(0, False)
        wait_for(lambda: io.input("estop") is True, what="e-stop through TPDO1")
        io.set_outputs({"coolant_flood": True})
        wait_for(lambda: sim.output(0), what="coolant output through RPDO1")
        assert changes == [("estop", True)]
        io.close()
    finally:
        sim.detach()
        node_net.disconnect()
        master.disconnect()
