"""A bench for simulated drives: the drives on one virtual bus, a minimal canopen master
(RemoteNode) on a second bus of the same channel, and a recorder of every frame the master
sees. Every wait polls a condition with a timeout; nothing sleeps and hopes.

Time: the bench stamps every SYNC it sends with an exact time (``Bench.sync_period_s``
apart, or ``at_s``) in the frame's timestamp, which the drives take as the SYNC's arrival
time; a slow or loaded machine changes nothing the drives feel. Tests of deadlines give a
drive a ``ManualClock`` instead."""

from __future__ import annotations

import functools

import configparser
import contextlib
import struct
import threading
import time
import uuid
from pathlib import Path
from typing import Iterator

import can
import canopen
import pytest

from nurbsmotion.sim import SimDrive, SimNetwork, default_eds_path
from tests.helpers import wait_for as _wait_for

TIMEOUT_S = 2.0


def rpdo(controlword: int, setpoint: int) -> bytes:
    """Data of the default RPDO1/RPDO2: controlword, then the CSP target or IP set-point."""
    return struct.pack("<Hi", controlword, setpoint)


wait_for = functools.partial(_wait_for, timeout_s=TIMEOUT_S, poll_s=0.001)  # the one helper, sim's waits


class ManualClock:
    """A drive clock that moves only when a test says so."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        return self.now_s

    def advance(self, seconds: float) -> float:
        self.now_s += seconds
        return self.now_s


class FrameLog(can.Listener):
    """Every frame the master receives, as (can_id, data, monotonic time)."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes, float]] = []
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self.frames.append((msg.arbitration_id, bytes(msg.data), time.monotonic()))

    def of(self, can_id: int) -> list[bytes]:
        with self._lock:
            return [data for cid, data, _ in self.frames if cid == can_id]

    def clear(self) -> None:
        with self._lock:
            self.frames.clear()


class Bench:
    """Drives under test plus the master side."""

    def __init__(self, sim: SimNetwork, master: canopen.Network, frames: FrameLog) -> None:
        self.sim = sim
        self.master = master
        self.frames = frames
        self.nodes: dict[int, canopen.RemoteNode] = {}
        self.sync_period_s = 1e-3  # SYNC stamps advance by this (the drives' default 0x60C2)
        self._wall_base_s = time.time()
        self.sync_time_s = 0.0  # of the last SYNC, relative to the bench start

    def add(self, node_id: int, **drive_kwargs: object) -> tuple[SimDrive, canopen.RemoteNode]:
        """Start drive ``node_id``; wait for its boot-up; return it and its master-side node."""
        drive = self.sim.add_drive(node_id, **drive_kwargs)
        node = canopen.RemoteNode(node_id, str(drive.eds_path))  # the master reads the drive's own EDS
        node.sdo.RESPONSE_TIMEOUT = 1.0
        self.master.add_node(node)
        self.nodes[node_id] = node
        wait_for(lambda: bytes([0]) in self.frames.of(0x700 + node_id), what=f"boot-up of node {node_id}")
        return drive, node

    def add_enabled(self, node_id: int, mode: int = 8, **drive_kwargs: object) -> tuple[SimDrive, canopen.RemoteNode]:
        """A drive in NMT OPERATIONAL and OPERATION ENABLED in ``mode`` (IP with bit 4)."""
        drive, node = self.add(node_id, **drive_kwargs)
        self.operational(node_id)
        self.enable(node_id, mode)
        return drive, node

    def send(self, can_id: int, data: bytes, at_s: float | None = None) -> None:
        """Send a frame; ``at_s`` (bench time, like ``sync_time_s``) stamps its arrival,
        else the drive stamps it with its own clock."""
        if at_s is None:
            self.master.send_message(can_id, data)
            return
        message = can.Message(arbitration_id=can_id, data=data, is_extended_id=False,
                              timestamp=self._wall_base_s + at_s)
        with self.master.send_lock:
            self.master.bus.send(message)

    def nmt(self, command: int, node_id: int) -> None:
        self.send(0x000, bytes([command, node_id]))

    def sync(self, counter: int | None = None, at_s: float | None = None) -> None:
        """Send one SYNC stamped ``sync_period_s`` after the previous one (or at ``at_s``)
        and wait until every drive on the bus has taken it."""
        drives = list(self.sim.drives.values())
        before = [d.stats.syncs for d in drives]
        operational = [d.nmt_state == 0x05 and not d.silent for d in drives]
        self.sync_time_s = self.sync_time_s + self.sync_period_s if at_s is None else at_s
        self.send(0x80, b"" if counter is None else bytes([counter]), at_s=self.sync_time_s)
        wait_for(
            lambda: all(d.stats.syncs > b or not op for d, b, op in zip(drives, before, operational)),
            what="SYNC processed",
        )
        # The drives sent this SYNC's TPDOs before counting it; wait until the master's
        # receive thread has logged them too.
        self.flush()

    def flush(self) -> None:
        """Wait until every frame sent so far by the drives reached the master's log."""
        marker = 0x7FF
        token = uuid.uuid4().bytes[:8]
        sim_net = self.sim.network
        assert sim_net is not None
        sim_net.send_message(marker, token)  # sent after the drives' frames: arrives after them
        wait_for(lambda: token in self.frames.of(marker), what="frames flushed")

    def operational(self, node_id: int) -> None:
        self.nmt(0x01, node_id)
        wait_for(lambda: self.sim.drives[node_id].nmt_state == 0x05, what="OPERATIONAL")

    def enable(self, node_id: int, mode: int = 8) -> None:
        """By SDO: mode, shutdown, switch on, enable operation (+ bit 4 in IP)."""
        node = self.nodes[node_id]
        node.sdo[0x6060].raw = mode
        for word in (0x06, 0x07, 0x0F):
            node.sdo[0x6040].raw = word
        if mode == 7:
            node.sdo[0x6040].raw = 0x1F


@pytest.fixture
def channel() -> str:
    return f"sim-test-{uuid.uuid4().hex}"


@contextlib.contextmanager
def open_bench(interface: str, channel: str) -> Iterator[Bench]:
    """Simulated drives and a master on ``interface``/``channel``; everything closed after."""
    frames = FrameLog()
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    # virtual: keep the stamps the bench puts on its frames (SYNC arrival times)
    master.connect(interface=interface, channel=channel, **({"preserve_timestamps": True} if interface == "virtual" else {}))
    assert master.notifier is not None
    master.notifier.add_listener(frames)
    sim = SimNetwork(interface=interface, channel=channel)
    try:
        sim.start()
        yield Bench(sim, master, frames)
    finally:
        sim.stop()
        master.disconnect()


@pytest.fixture
def bench(channel: str) -> Iterator[Bench]:
    with open_bench("virtual", channel) as opened:
        yield opened


def derived_eds(directory: Path, drop: tuple[str, ...] = (), change: dict[str, dict[str, str | None]] | None = None) -> Path:
    """The packaged EDS with sections dropped (``"6066"``, ``"1600sub2"``) and keys changed
    (``{"607A": {"PDOMapping": "0"}}``; None removes the key; a new section is created), so a
    test can describe exactly the drive whose rule it checks."""
    eds = configparser.RawConfigParser()
    eds.optionxform = str  # keep the keys' case
    eds.read(default_eds_path(), encoding="ascii")
    for section in drop:
        eds.remove_section(section)
    for section, keys in (change or {}).items():
        if not eds.has_section(section):
            eds.add_section(section)
        for key, value in keys.items():
            if value is None:
                eds.remove_option(section, key)
            else:
                eds.set(section, key, value)
    path = directory / f"derived-{uuid.uuid4().hex[:8]}.eds"
    with path.open("w", encoding="ascii") as out:
        eds.write(out)
    return path


def variable_section(name: str, data_type: int, access: str, default: str | None = "0") -> dict[str, str | None]:
    """Keys of a VAR section for ``derived_eds`` (e.g. 0x1007, 0x1019 the packaged EDS lacks)."""
    return {"ParameterName": name, "ObjectType": "0x7", "DataType": f"0x{data_type:04X}", "AccessType": access,
            "DefaultValue": default, "PDOMapping": "0"}
