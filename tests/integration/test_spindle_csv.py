"""A cyclic synchronous velocity (csv, mode 9) spindle through the daemon in this process
(simulated drives on a private virtual bus): 0x60FF goes in the spindle's RPDO1 with every
SYNC, ramped per cycle, not by SDO; the job's traffic record shows it frame by frame."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import pytest

from nurbsmotion.service.daemon import Daemon
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for

SPINDLE = "spindle: {node_id: 5, mode: csv, counts_per_rev: 4096, max_rpm: 12000, accel_rpm_s: 20000}\n"
STEP_COUNTS_S = 20000 * 4096 / 60 * 0.004  # accel_rpm_s in counts/s² x the 4 ms cycle


@pytest.fixture
def machine(tmp_path: Path) -> Iterator[Daemon]:
    with daemon_in_process(tmp_path / "data", SPINDLE, "csv") as daemon:
        yield daemon


def frames(folder: Path, cob_id: int) -> list[bytes]:
    """The data of every frame with ``cob_id`` in the job's candump-format traffic record."""
    out = []
    for line in (folder / "traffic.log").read_text().splitlines():
        can_id, _, data = line.split()[2].partition("#")
        if int(can_id, 16) == cob_id:
            out.append(bytes.fromhex(data))
    return out


def test_m3_ramps_0x60ff_per_sync_in_the_spindles_rpdo(machine):
    controller = machine.controller
    drive = machine.simulation.network[5]
    job = controller.submit("mill.nc", "G21 G90\nS6000 M3\nG01 X5 F3000\nM5\nG01 X0 F600\n")["job"]["id"]
    info = wait_for(lambda: (i := controller.job_info(job)["job"]).get("outcome") and i, 30.0, "job end")
    outcome = info["outcome"]
    assert outcome["outcome"] == "completed", outcome["reason"]
    assert [(e.get("code"), e.get("at_speed")) for e in outcome["machine_events"]][0] == ("M3", True)

    folder = Path(info["folder"])
    syncs = len(frames(folder, 0x80))
    velocity = [struct.unpack("<i", d)[0] for d in frames(folder, 0x205)]
    assert abs(len(velocity) - syncs) <= 1  # one 0x60FF per SYNC
    target = round(6000 * 4096 / 60)
    assert max(velocity) == target
    steps = [b - a for a, b in zip(velocity, velocity[1:])]
    assert max(abs(s) for s in steps) <= STEP_COUNTS_S + 1  # ramped per cycle, both ways (M3, then M5)
    assert sum(1 for s in steps if s > 0) >= target / STEP_COUNTS_S - 1  # many small steps, not a jump
    assert velocity[-1] == 0  # M5 ramped it down during the last move (0.3 s of its 0.5 s)
    sdo_writes = [d for d in frames(folder, 0x605) if d[0] & 0xE0 == 0x20 and d[1:3] == b"\xff\x60"]
    assert sdo_writes == []  # no 0x60FF by SDO during the job
    wait_for(lambda: drive.axis.velocity_actual == 0, 5.0, "spindle at rest")
    assert drive.axis.mode == 9
