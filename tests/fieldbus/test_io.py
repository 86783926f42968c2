"""The master's side of the CiA-401 I/O node: named bits, bring-up, TPDO in, RPDO out,
against the simulated node on python-can's virtual bus."""

from __future__ import annotations

import contextlib
import time
import uuid
from collections.abc import Iterator

import canopen
import pytest

from nurbsmotion.can.cia402 import NmtState
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.io import (
    IoNode,
    cia401_dictionary,
    input_states,
    output_groups,
)
from nurbsmotion.config.io import IoConfig, IoSignal
from nurbsmotion.sim.io_node import SimIoNode
from tests.helpers import wait_for

IO = IoConfig(12, inputs=(IoSignal("estop", 0, active_low=True), IoSignal("limit_x_min", 1),
                          IoSignal("probe", 10)),
              outputs=(IoSignal("coolant_flood", 0), IoSignal("coolant_mist", 1), IoSignal("lamp_ok", 9, True)))


def test_input_states_by_bit_and_polarity():
    assert input_states(b"\x01\x00", IO.inputs) == {"estop": False, "limit_x_min": False, "probe": False}
    assert input_states(b"\x02\x04", IO.inputs) == {"estop": True, "limit_x_min": True, "probe": True}


def test_output_groups_by_name_and_polarity():
    assert output_groups({}, IO.outputs, 2) == b"\x00\x02"  # lamp_ok is active low: off = bit high
    assert output_groups({"coolant_mist": True, "lamp_ok": True}, IO.outputs, 2) == b"\x02\x00"


def test_dictionary_holds_the_used_groups_only():
    od = cia401_dictionary(IO)
    assert sorted(od[0x6000].subindices) == [0, 1, 2] and sorted(od[0x6200].subindices) == [0, 1, 2]
    assert od[0x6000][1].pdo_mappable and not od[0x6000][1].writable and od[0x6200][2].writable


@contextlib.contextmanager
def io_bus(sim: SimIoNode) -> Iterator[canopen.Network]:
    channel = f"io-master-{uuid.uuid4().hex}"
    master, node_net = canopen.Network(), canopen.Network()
    for net in (master, node_net):
        net.NOTIFIER_CYCLE = 0.05
        net.connect(interface="virtual", channel=channel)
    sim.attach(node_net)
    try:
        yield master
    finally:
        sim.detach()
        node_net.disconnect()
        master.disconnect()


def test_bring_up_inputs_and_outputs_with_the_simulated_node():
    sim = SimIoNode(12, input_groups=2, output_groups=2)
    sim.set_input(0, True)  # e-stop contact closed: not pressed
    with io_bus(sim) as master:
        changes: list[tuple[str, bool]] = []
        io = IoNode(master, IO, on_change=lambda name, active: changes.append((name, active)))
        io.bring_up(heartbeat_producer_ms=50)
        assert io.inputs == {"estop": False, "limit_x_min": False, "probe": False}  # read by SDO before start
        wait_for(lambda: sim.outputs == b"\x00\x02", 2.0, what="initial outputs (lamp_ok off = high)")
        sim.set_input(0, False)  # e-stop pressed (contact opens)
        wait_for(lambda: io.input("estop") is True, 2.0, what="estop via TPDO1")
        assert changes == [("estop", True)]
        sim.set_input(10, True)
        wait_for(lambda: io.input("probe") is True, 2.0, what="probe")
        io.set_outputs({"coolant_flood": True, "lamp_ok": True})
        wait_for(lambda: sim.outputs == b"\x01\x00", 2.0, what="outputs via RPDO1")
        assert sim.output(0) and not sim.output(9)
        # what bring-up configured in the node: event-driven PDO 1 mapping the two groups
        assert sim.node.sdo[0x1800][2].raw == 255 and sim.node.sdo[0x1A00][0].raw == 2
        with pytest.raises(KeyError, match="node 12: no output named spindle"):
            io.set_outputs({"spindle": True})
        io.close()


def test_node_without_enough_inputs_is_refused_naming_node_and_object():
    sim = SimIoNode(12, input_groups=1, output_groups=2)
    with io_bus(sim) as master:
        io = IoNode(master, IO)
        with pytest.raises(FieldbusError, match=r"node 12: bring-up step 'I/O inputs': 0x6000 has 1 groups of 8 "
                                                r"inputs, the io section needs 2"):
            io.bring_up(heartbeat_producer_ms=50)
        assert sim.nmt_state == 0x7F  # nothing started


def test_a_drive_at_the_io_node_id_is_refused():
    from nurbsmotion.sim import SimNetwork

    channel = f"io-drive-{uuid.uuid4().hex}"
    with SimNetwork(interface="virtual", channel=channel) as sim:
        sim.add_drive(12)
        master = canopen.Network()
        master.NOTIFIER_CYCLE = 0.05
        master.connect(interface="virtual", channel=channel)
        try:
            with pytest.raises(FieldbusError, match=r"node 12: bring-up step 'I/O device type': 0x1000 = 0x[0-9A-F]{8}: "
                                                    r"not a CiA-401 I/O device"):
                IoNode(master, IO).bring_up(heartbeat_producer_ms=50)
        finally:
            master.disconnect()


class JudgingClock:
    """The master's judging time (perf_counter) until a test stops it; then it moves only
    when the test advances it (the heartbeat watch's clock, injected as the master's is)."""

    def __init__(self) -> None:
        self.stopped_at: float | None = None

    def __call__(self) -> float:
        return time.perf_counter() if self.stopped_at is None else self.stopped_at

    def stop(self) -> None:
        self.stopped_at = time.perf_counter()

    def advance(self, seconds: float) -> None:
        assert self.stopped_at is not None
        self.stopped_at += seconds


def silence_ms(message: str) -> int:
    """N of 'io node 12: no heartbeat for N ms (consumer time 200 ms)'."""
    return int(message.split("no heartbeat for ")[1].split(" ms")[0])


def test_the_master_consumes_the_nodes_heartbeat_and_the_node_the_masters():
    sim = SimIoNode(12, input_groups=2, output_groups=2)
    sim.set_input(0, True)
    clock = JudgingClock()
    with io_bus(sim) as master:
        lost: list[str] = []
        io = IoNode(master, IO, on_lost=lost.append, judging_time_s=clock)
        io.bring_up(heartbeat_producer_ms=50, heartbeat_consumer_ms=200, master_heartbeat=(127, 500))
        assert sim.node.sdo[0x1016][1].raw == 127 << 16 | 500  # the node watches the master (CiA 301 0x1016:01)
        time.sleep(0.4)  # heartbeats every 50 ms: nothing lost
        assert lost == [] and io.lost is None and io.input("estop") is False
        sim.detach()  # the node goes silent
        clock.stop()
        clock.advance(0.05)  # less than the consumer time since the last heartbeat: not lost
        time.sleep(0.15)  # the watch looks every 50 ms
        assert lost == []
        clock.advance(0.25)
        wait_for(lambda: lost, 2.0, "the loss")
        assert len(lost) == 1 and lost[0].startswith("io node 12: no heartbeat for ")
        assert 300 <= silence_ms(lost[0]) < 500  # judged at the advanced time: the last heartbeat < 200 ms before
        assert lost[0].endswith(" ms (consumer time 200 ms)")
        assert io.inputs is None and io.input("estop") is None  # unknown: an unread e-stop counts as pressed
        io.close()


def test_a_restarted_node_is_lost_and_a_second_bring_up_revives_it():
    sim = SimIoNode(12, input_groups=2, output_groups=2)
    with io_bus(sim) as master:
        lost: list[str] = []
        io = IoNode(master, IO, on_lost=lost.append)
        io.bring_up(heartbeat_producer_ms=50, heartbeat_consumer_ms=300)
        master.nmt.send_command(0x81)  # NMT reset node: boot-up, defaults, PRE-OPERATIONAL
        wait_for(lambda: lost, 2.0, "the loss")
        assert lost == ["io node 12: heartbeat reports boot-up: the node restarted (its PDO mapping and outputs are "
                        "back to defaults)"]
        io.bring_up(heartbeat_producer_ms=50, heartbeat_consumer_ms=300)
        assert io.lost is None and io.inputs is not None
        # the bring-up's NMT start is not confirmed (CiA 301): the input changes once the node
        # is OPERATIONAL (set at once, a loaded host's node could still be PRE-OPERATIONAL and
        # never send the change: CiA 401 TPDOs are sent on a change only)
        wait_for(lambda: sim.nmt_state is NmtState.OPERATIONAL, 2.0, "the node OPERATIONAL again")
        sim.set_input(10, True)
        wait_for(lambda: io.input("probe") is True, 2.0, what="TPDO1 after the second bring-up")
        time.sleep(0.4)
        assert len(lost) == 1
        io.close()
