"""The simulated CiA-401 I/O node seen from a canopen master on python-can's virtual bus."""

from __future__ import annotations

import contextlib
import time
import uuid
from collections.abc import Iterator

import canopen
import pytest
from canopen.sdo import SdoAbortedError
from conftest import FrameLog, wait_for

from nurbsmotion.sim.io_node import SimIoNode

NODE = 10
TPDO1, RPDO1, HEARTBEAT = 0x180 + NODE, 0x200 + NODE, 0x700 + NODE


class IoBench:
    def __init__(self, io: SimIoNode, master: canopen.Network, frames: FrameLog) -> None:
        self.io, self.master, self.frames = io, master, frames
        self.node = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
        self.node.sdo.RESPONSE_TIMEOUT = 1.0
        master.add_node(self.node)

    def nmt(self, command: int) -> None:
        self.master.send_message(0, bytes([command, NODE]))

    def operational(self) -> None:
        self.nmt(0x01)
        wait_for(lambda: self.io.nmt_state == 0x05, what="OPERATIONAL")

    def read(self, index: int, sub: int) -> int:
        return int.from_bytes(self.node.sdo.upload(index, sub), "little")

    def write(self, index: int, sub: int, value: int, size: int) -> None:
        self.node.sdo.download(index, sub, value.to_bytes(size, "little"))

    def sync(self) -> None:
        self.master.send_message(0x80, b"")


@contextlib.contextmanager
def open_io(inputs: int = 2, outputs: int = 1) -> Iterator[IoBench]:
    channel = f"io-test-{uuid.uuid4().hex}"
    frames = FrameLog()
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(interface="virtual", channel=channel)
    master.notifier.add_listener(frames)
    node_net = canopen.Network()
    node_net.NOTIFIER_CYCLE = 0.05
    node_net.connect(interface="virtual", channel=channel)
    io = SimIoNode(NODE, inputs, outputs)
    try:
        io.attach(node_net)
        wait_for(lambda: b"\x00" in frames.of(HEARTBEAT), what="boot-up")
        yield IoBench(io, master, frames)
    finally:
        io.detach()
        node_net.disconnect()
        master.disconnect()


@pytest.fixture
def bench() -> Iterator[IoBench]:
    with open_io() as opened:
        yield opened


def test_objects_of_a_cia401_node(bench: IoBench) -> None:
    assert bench.read(0x1000, 0) & 0xFFFF == 0x0191
    assert bench.read(0x6000, 0) == 2 and bench.read(0x6200, 0) == 1
    assert bench.read(0x1A00, 0) == 2 and bench.read(0x1A00, 1) == 0x6000_0108 and bench.read(0x1A00, 2) == 0x6000_0208
    assert bench.read(0x1600, 1) == 0x6200_0108
    with pytest.raises(SdoAbortedError):
        bench.read(0x6000, 3)  # only the declared groups exist
    with pytest.raises(SdoAbortedError):
        bench.write(0x6000, 1, 1, 1)  # inputs are read only


def test_inputs_are_sent_on_change_only_in_operational(bench: IoBench) -> None:
    bench.io.set_input(3, True)  # PRE-OPERATIONAL: no PDO, but SDO reads the input
    assert bench.read(0x6000, 1) == 0x08
    bench.operational()
    bench.read(0x1000, 0)  # a round trip later: nothing was sent on entering OPERATIONAL
    assert bench.frames.of(TPDO1) == []
    bench.io.set_input(9, True)  # estop on group 2, bit 1
    wait_for(lambda: bench.frames.of(TPDO1)[-1:] == [b"\x08\x02"], what="TPDO1 on change")
    bench.io.set_input(9, True)  # no change, no frame
    bench.sync()
    bench.io.set_input(0, True)
    wait_for(lambda: bench.frames.of(TPDO1)[-1:] == [b"\x09\x02"], what="next change")
    assert len(bench.frames.of(TPDO1)) == 2


def test_synchronous_transmission_type_sends_on_every_sync(bench: IoBench) -> None:
    bench.write(0x1800, 2, 1, 1)  # type 1: every SYNC
    bench.operational()
    bench.frames.clear()
    bench.io.set_input(1, True)
    for _ in range(3):
        bench.sync()
    wait_for(lambda: len(bench.frames.of(TPDO1)) == 3, what="3 TPDOs on 3 SYNCs")
    assert set(bench.frames.of(TPDO1)) == {b"\x02\x00"}


def test_outputs_follow_rpdo1_in_operational_and_drop_on_stop(bench: IoBench) -> None:
    bench.master.send_message(RPDO1, b"\x05")
    bench.read(0x1000, 0)  # a round trip later: the RPDO was ignored in PRE-OPERATIONAL
    assert bench.io.outputs == b"\x00"
    bench.operational()
    bench.master.send_message(RPDO1, b"\x05")
    wait_for(lambda: bench.io.outputs == b"\x05", what="outputs set")
    assert bench.io.output(0) and bench.io.output(2) and not bench.io.output(1)
    assert bench.read(0x6200, 1) == 5
    bench.nmt(0x02)  # STOPPED: outputs take the error value
    wait_for(lambda: bench.io.nmt_state == 0x04, what="STOPPED")
    assert bench.io.outputs == b"\x00"


def test_short_rpdo_is_refused_with_emcy() -> None:
    with open_io(outputs=2) as two:
        two.operational()
        two.master.send_message(RPDO1, b"\x01")
        wait_for(lambda: bool(two.frames.of(0x80 + NODE)), what="EMCY")
        assert two.frames.of(0x80 + NODE)[0][:2] == b"\x10\x82"
        assert two.io.outputs == b"\x00\x00"


def test_remap_follows_cia301_procedure(bench: IoBench) -> None:
    with pytest.raises(SdoAbortedError):
        bench.write(0x1A00, 0, 1, 1)  # the PDO is valid: mapping may not change
    bench.write(0x1800, 1, 0x8000_0000 | TPDO1, 4)
    bench.write(0x1A00, 0, 0, 1)
    bench.write(0x1A00, 0, 1, 1)
    bench.write(0x1800, 1, TPDO1, 4)
    bench.operational()
    bench.io.set_input(8, True)
    bench.io.set_input(0, True)
    wait_for(lambda: bench.frames.of(TPDO1)[-1:] == [b"\x01"], what="one-byte TPDO1")


def test_heartbeat_state_and_consumer_loss_switches_outputs_off(bench: IoBench) -> None:
    bench.write(0x1017, 0, 10, 2)
    wait_for(lambda: b"\x7f" in bench.frames.of(HEARTBEAT), what="heartbeat PRE-OPERATIONAL")
    bench.write(0x1016, 1, 0x7F << 16 | 1000, 4)  # watch node 127 (the master), 1 s
    bench.operational()
    wait_for(lambda: bench.frames.of(HEARTBEAT)[-1:] == [b"\x05"], what="heartbeat OPERATIONAL")
    bench.master.send_message(RPDO1, b"\x01")
    wait_for(lambda: bench.io.outputs == b"\x01", what="output on")
    bench.master.send_message(0x77F, b"\x05")
    wait_for(lambda: bench.io._heartbeat_consumer.next_deadline() < float("inf"), what="master heartbeat seen")
    now = time.monotonic()
    bench.io.tick(now)
    assert bench.io.outputs == b"\x01"
    bench.io.tick(now + 2.0)  # no master heartbeat for 2 s > 1 s
    assert bench.io.outputs == b"\x00"
    wait_for(lambda: bool(bench.frames.of(0x80 + NODE)), what="EMCY 0x8130")
    assert bench.frames.of(0x80 + NODE)[-1][:2] == b"\x30\x81"


def test_reset_node_restores_defaults_and_boots(bench: IoBench) -> None:
    bench.write(0x1800, 2, 1, 1)
    bench.frames.clear()
    bench.nmt(0x81)
    wait_for(lambda: b"\x00" in bench.frames.of(HEARTBEAT), what="boot-up after reset")
    assert bench.read(0x1800, 2) == 255
