"""Fixtures for tests on a real kernel SocketCAN vcan0 (run them through scripts/with-vcan).

Every test module here sets `pytestmark = pytest.mark.vcan`, and each test skips with the
reason when vcan0 is not up: a plain `pytest` outside the runner reports skips, not failures.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import can
import pytest

CHANNEL = "vcan0"
# Inside User-Mode Linux a Python bus.send costs ~120-270 us: cycles of 4 ms (reference §5).
CYCLE_PERIOD_S = 0.004
# Machines of five nodes in two Python processes (daemon + `nurbsmotion sim`: three axes, a
# spindle or homing sensors, an I/O node) saturate the guest's one CPU at 4 ms: the drives'
# process then lags the wire by seconds and its SDO answers come too late (docs/vcan.md,
# "Cycles inside UML"). Those tests run at 8 ms; what they check (homing, spindle, I/O) does
# not depend on the period, and tolerances that do are derived from it.
SLOW_GUEST_CYCLE_PERIOD_S = 0.008


def vcan0_missing_reason() -> str | None:
    """Why vcan0 cannot be used here, or None when it is up."""
    flags_file = Path("/sys/class/net") / CHANNEL / "flags"
    if not flags_file.exists():
        return f"no {CHANNEL} here: run through scripts/with-vcan (docs/vcan.md)"
    if not int(flags_file.read_text(), 16) & 0x1:  # IFF_UP
        return f"{CHANNEL} is down: `ip link set up {CHANNEL}` or use scripts/with-vcan"
    return None


@pytest.fixture
def vcan0() -> str:
    """The channel name, after checking vcan0 is up (else the test is skipped)."""
    reason = vcan0_missing_reason()
    if reason is not None:
        pytest.skip(reason)
    return CHANNEL


@pytest.fixture
def sim_process(vcan0: str, tmp_path: Path) -> Iterator:
    """Factory: the simulated drives of a config in a child process, ready; always stopped."""
    from tests.vcan.two_processes import SimProcess  # here: it imports this module

    started: list[SimProcess] = []

    def start(config_path: Path) -> SimProcess:
        sim = SimProcess(config_path, tmp_path / "recordings")
        started.append(sim)
        sim.wait_ready()
        return sim

    yield start
    for sim in started:
        sim.stop()


@pytest.fixture
def open_bus(vcan0: str) -> Iterator:
    """Factory of socketcan buses on vcan0 listening to the given ids; all shut down after."""
    buses: list[can.BusABC] = []

    def open_bus_for(*can_ids: int) -> can.BusABC:
        filters = [{"can_id": can_id, "can_mask": 0x7FF, "extended": False} for can_id in can_ids]
        bus = can.Bus(interface="socketcan", channel=vcan0, can_filters=filters or None)
        buses.append(bus)
        return bus

    yield open_bus_for
    for bus in buses:
        bus.shutdown()

