"""Helpers every test folder shares (``from tests.helpers import wait_for``): one polling wait,
a master on simulated drives, and what holds an array's memory."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

import can

from nurbsmotion.config import MachineConfig
from nurbsmotion.fieldbus import Master
from nurbsmotion.sim import SimNetwork

T = TypeVar("T")
WAIT_S = 30.0  # a wait ends as soon as its condition holds; a loaded host must not fail it


def wait_for(condition: Callable[[], T], timeout_s: float = WAIT_S, what: str = "condition", poll_s: float = 0.01) -> T:
    """Call ``condition`` every ``poll_s`` until it returns a true value, and return that value;
    AssertionError naming ``what`` once ``timeout_s`` passed without one. A module whose
    waits are shorter binds its own (functools.partial)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


@dataclass
class SimulatedMachine:
    config: MachineConfig
    master: Master
    sim: SimNetwork
    probe: can.BusABC  # a second bus on the channel: frames a test injects reach master and drives


def memory_of(values: Any) -> object:
    """The object that owns an array's memory, its bases followed (an mmap.mmap: a mapped file)."""
    while getattr(values, "base", None) is not None:
        values = values.base
    return values.obj if isinstance(values, memoryview) else values


@contextlib.contextmanager
def simulated_machine(config: MachineConfig, drives: dict[int, dict[str, Any]], bring_up: bool = True,
                      **master_kw: Any) -> Iterator[SimulatedMachine]:
    """Simulated drives (node id -> SimNetwork.add_drive keywords) on the configuration's
    virtual channel, a master for its axes (brought up unless ``bring_up`` is false) and a
    probe bus; torn down whatever happens."""
    channel = config.bus.channel
    sim = SimNetwork(channel=channel)
    for node, drive_kw in drives.items():
        sim.add_drive(node, **drive_kw)
    sim.start()
    bus = can.Bus(interface="virtual", channel=channel)
    probe = can.Bus(interface="virtual", channel=channel)
    master_kw.setdefault("bootup_timeout_s", 1.0)
    master = Master(config, bus, **master_kw)
    try:
        if bring_up:
            master.bring_up()
        yield SimulatedMachine(config, master, sim, probe)
    finally:
        master.shutdown()
        probe.shutdown()
        bus.shutdown()
        sim.stop()
