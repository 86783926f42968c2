"""Bring-up from the EDS against simulated drives built from the same EDS (same process):
split PDOs, the master's heartbeat consumed by the drives, SDO aborts naming the object."""

from __future__ import annotations

import contextlib
import time
import uuid
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from nurbsmotion.can import cia402 as c
from nurbsmotion.config import parse_config
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus import Master
from tests.fieldbus.eds_variants import eds_variant, one_entry_pdos
from tests.helpers import simulated_machine, wait_for

sim_package = pytest.importorskip("nurbsmotion.sim")
FaultInjection, SimNetwork = sim_package.FaultInjection, sim_package.SimNetwork

WAIT_S = 30.0


@contextlib.contextmanager
def rig(mode: str = "csp", eds: Path | None = None, n_axes: int = 2, master_heartbeat_ms: int = 50,
        bring_up: bool = True) -> Iterator[tuple[Master, SimNetwork]]:
    channel = "bu-" + uuid.uuid4().hex
    eds_line = f", eds: {eds}" if eds else ""
    axes = "".join(f"  - {{name: {'XYZ'[i]}, node_id: {i + 1}, mode: {mode}{eds_line}}}\n" for i in range(n_axes))
    cfg = parse_config(f"cycle_period_ms: 4\nbus: {{interface: virtual, channel: {channel}}}\n"
                       f"monitoring: {{heartbeat_producer_ms: 50, heartbeat_consumer_ms: 600, "
                       f"master_heartbeat_ms: {master_heartbeat_ms}, master_heartbeat_consumer_multiple: 4}}\n"
                       f"axes:\n{axes}", "rig.yaml")
    with simulated_machine(cfg, {node: {"eds": eds} for node in range(1, n_axes + 1)}, bring_up) as machine:
        yield machine.master, machine.sim


def test_drives_get_the_master_heartbeat_consumer_entry():
    with rig() as (master, sim):
        for node in (1, 2):
            assert sim[node].value(c.CONSUMER_HEARTBEAT_TIME, 1) == 127 << 16 | 200
            assert sim[node].value(c.QUICK_STOP_OPTION) == 2
        assert master.status().phase == "holding"


def test_silent_master_heartbeat_faults_every_drive_within_the_consumer_time():
    with rig() as (master, sim):
        assert master._heartbeat is not None
        stopped = time.monotonic()
        master._heartbeat.stop()  # as if the daemon died: nothing else changes
        try:
            wait_for(lambda: all(sim[n].state == c.State.FAULT for n in (1, 2)), 5.0)
        except AssertionError:
            raise AssertionError(f"drive states {[sim[n].state for n in (1, 2)]}, errors "
                                 f"{[hex(sim[n].axis.error_code) for n in (1, 2)]}, master {master.status().phase}, "
                                 f"faults {[f.message for f in master.faults()]}") from None
        # consumer time 200 ms; the generous bound only absorbs a loaded machine's thread scheduling
        assert time.monotonic() - stopped < 2.0
        assert all(sim[n].axis.error_code == c.EmcyCode.HEARTBEAT for n in (1, 2))


@pytest.mark.parametrize("mode", ["csp", "ip"])
def test_one_entry_pdos_run_split_controlword_and_set_point(tmp_path, mode):
    eds = eds_variant(tmp_path, "one_entry.eds", **one_entry_pdos())
    with rig(mode, eds) as (master, sim):
        assert [len(f.fields) for f in master.plans[0].layout.rpdos] == [1, 1]
        k = np.arange(200)
        counts = np.column_stack([np.round(3000 * np.sin(2 * np.pi * k / 200))] * 2).astype(np.int32)
        result = master.stream(counts).wait(WAIT_S)
        assert result is not None and result.outcome == "done", result
        def applied() -> list[int]:
            records = [r.setpoint_counts for r in sim[1].recorder.records()]
            start = records.index(int(counts[1, 0])) - 1
            return records[start:start + 200]
        wait_for(lambda: len(applied()) == 200, 5.0)  # the last row is applied at the next SYNC
        assert applied() == counts[:, 0].tolist()  # every row applied once, in order


def test_sdo_abort_names_the_object_in_hex_and_words():
    with rig(bring_up=False) as (master, sim):
        sim.inject(FaultInjection("sdo_abort", node_id=2, index=0x1600, subindex=2, code=0x0604_0041))
        with pytest.raises(FieldbusError) as info:
            master.bring_up()
        assert str(info.value) == ("node 2: bring-up step 'map RPDO1': SDO abort 0x06040041 (Object cannot be "
                                   "mapped to the PDO) writing 0x1600:02 = 0x607A0020 (0x607A:00, 32 bit)")
