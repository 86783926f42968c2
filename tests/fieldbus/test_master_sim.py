"""The master against simulated CiA-402 drives on a private virtual bus (same process).

Assertions are on content (recorded set-points, reports, states), never on timing; every
wait has a generous time-out so a loaded 2-core machine does not make them flaky.
"""

from __future__ import annotations

import contextlib
import uuid
from typing import Iterator

import can
from can.interfaces.virtual import VirtualBus
import numpy as np
import pytest

from nurbsmotion.can.cia402 import State
from nurbsmotion.config import parse_config
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus import Master
from tests.helpers import simulated_machine, wait_for

sim_package = pytest.importorskip("nurbsmotion.sim")
FaultInjection, SimNetwork = sim_package.FaultInjection, sim_package.SimNetwork

WAIT_S = 30.0


def make_config(channel: str, mode: str = "csp", n_axes: int = 3, period_ms: float = 4, extra: str = "",
                identity: str = ""):
    axes = "".join(f"  - {{name: {'XYZABC'[i]}, node_id: {i + 1}, mode: {mode}, counts_per_mm: 1000,"
                   f" max_accel_mm_s2: 2000{identity if i == 0 else ''}}}\n" for i in range(n_axes))
    text = (f"cycle_period_ms: {period_ms}\nbus: {{interface: virtual, channel: {channel}}}\n"
            f"monitoring: {{heartbeat_producer_ms: 50, heartbeat_consumer_ms: 600}}\n{extra}axes:\n{axes}")
    return parse_config(text, "test.yaml")


@contextlib.contextmanager
def rig(mode: str = "csp", n_axes: int = 3, simulated: int | None = None, bring_up: bool = True,
        identity: str = "", **master_kw) -> Iterator[tuple[Master, SimNetwork, can.BusABC]]:
    """Simulated drives 1..simulated, a master for axes 1..n_axes, and a probe bus on which a
    test can send frames of its own (a bus does not hear itself); torn down whatever happens."""
    config = make_config("fb-" + uuid.uuid4().hex, mode, n_axes, identity=identity)
    drives = {node: {"identity": (0x1234, 0x42)} for node in range(1, (simulated if simulated is not None else n_axes) + 1)}
    with simulated_machine(config, drives, bring_up, **master_kw) as machine:
        yield machine.master, machine.sim, machine.probe


def sine_counts(n: int = 300, n_axes: int = 3, amplitude: int = 5000) -> np.ndarray:
    k = np.arange(n)
    cols = [np.round(amplitude * np.sin(2 * np.pi * (j + 1) * k / n)) for j in range(n_axes)]
    return np.column_stack(cols).astype(np.int32)


def recorded(sim: SimNetwork, node: int) -> tuple[list[int], list[int]]:
    records = sim[node].recorder.records()
    return [r.sync_index for r in records], [r.setpoint_counts for r in records]


def demand_at_syncs(sim: SimNetwork, node: int, syncs: list[int]) -> np.ndarray:
    """The set-point drive ``node`` followed at each of ``syncs``: a SYNC without a new
    set-point records nothing and keeps the previous one (docs/sim.md), so two drives'
    recordings need not line up index for index."""
    recorded_syncs, setpoints = recorded(sim, node)
    return np.asarray(setpoints, dtype=float)[np.searchsorted(recorded_syncs, syncs, side="right") - 1]


def distance_to_polyline(point: np.ndarray, vertices: np.ndarray) -> float:
    """Least Euclidean distance from ``point`` to the segments joining consecutive ``vertices``."""
    a, b = vertices[:-1], vertices[1:]
    ab = b - a
    length2 = np.maximum((ab * ab).sum(axis=1), 1e-12)
    u = np.clip(((point - a) * ab).sum(axis=1) / length2, 0.0, 1.0)
    return float(np.hypot(*(a + u[:, None] * ab - point).T).min())


def find_run(values: list[int], planned: list[int]) -> int:
    """Start of ``planned`` as a contiguous run inside ``values`` (-1 if absent)."""
    n = len(planned)
    for start in range(len(values) - n + 1):
        if values[start:start + n] == planned:
            return start
    return -1


@pytest.mark.parametrize("mode", ["ip", "csp"])
def test_stream_reaches_every_drive_once_per_sync(mode):
    counts = sine_counts()
    with rig(mode) as (master, sim, _):
        assert [a.state for a in master.status().axes] == ["OPERATION ENABLED"] * 3
        job = master.stream(counts)
        result = job.wait(WAIT_S)
        assert result is not None and result.outcome == "done" and result.sent == len(counts)
        wait_for(lambda: all(len(sim[n].recorder) > 0 and recorded(sim, n)[1][-1] == counts[-1, n - 1]
                             for n in (1, 2, 3)))
        for node in (1, 2, 3):
            syncs, setpoints = recorded(sim, node)
            start = find_run(setpoints, counts[:, node - 1].tolist())
            assert start >= 0, f"node {node}: planned set-points not found in order"
            window = syncs[start:start + len(counts)]
            assert window == list(range(window[0], window[0] + len(counts)))  # one per SYNC, none missing
        assert master.status().phase == "holding"


def test_hold_keeps_drives_enabled_at_the_last_setpoint():
    counts = sine_counts(100)
    progress: list[tuple[int, int]] = []
    with rig() as (master, sim, _):
        assert master.stream(counts, on_progress=lambda sent, n: progress.append((sent, n))).wait(WAIT_S).outcome \
            == "done"
        assert progress and all(n == len(counts) for _, n in progress)
        assert [sent for sent, _ in progress] == sorted(sent for sent, _ in progress)
        cycle = master.status().cycle
        wait_for(lambda: master.status().cycle > cycle + 20)
        status = master.status()
        assert status.phase == "holding"
        assert [a.setpoint_counts for a in status.axes] == counts[-1].tolist()
        assert all(sim[n].state is State.OPERATION_ENABLED for n in (1, 2, 3))


def test_fault_bit_quick_stops_every_axis_and_names_node_and_code():
    with rig() as (master, sim, _):
        job = master.stream(sine_counts(2000))
        wait_for(lambda: (master.status().job_index or 0) > 50)
        sim.inject(FaultInjection("fault", node_id=2, code=0x2310))
        result = job.wait(WAIT_S)
        assert result.outcome == "faulted"
        kinds = {(f.node_id, f.kind) for f in result.faults}
        assert (2, "fault_bit") in kinds
        emcy = [f for f in result.faults if f.kind == "emcy"]
        assert emcy and emcy[0].node_id == 2 and emcy[0].code == 0x2310 and "0x2310" in emcy[0].message
        assert all(f.cycle > 0 for f in result.faults)
        wait_for(lambda: master.status().phase == "disabled")
        assert sim[2].state is State.FAULT
        assert all(sim[n].state is not State.OPERATION_ENABLED for n in (1, 3))


def test_emcy_while_drives_follow_gives_a_controlled_stop_on_the_path():
    counts = sine_counts(2000, amplitude=20000)
    with rig() as (master, sim, probe):
        job = master.stream(counts)
        wait_for(lambda: (master.status().job_index or 0) > 200)
        probe.send(can.Message(arbitration_id=0x80 + 3, data=bytes([0x10, 0x42, 0x08, 0, 0, 0, 0, 0]),
                             is_extended_id=False))  # temperature warning, drive keeps running
        result = job.wait(WAIT_S)
        assert result.outcome == "faulted"
        assert [(f.node_id, f.kind, f.code) for f in result.faults] == [(3, "emcy", 0x4210)]
        assert result.sent < len(counts)
        assert master.status().phase == "holding"
        assert all(sim[n].state is State.OPERATION_ENABLED for n in (1, 2, 3))
        cycle = master.status().cycle
        wait_for(lambda: master.status().cycle > cycle + 10)  # the drives applied the last ones
        # the stop stays on the planned polyline of axis 1 -> 2 (they move as sin(t), sin(2t))
        syncs, x = recorded(sim, 1)
        start = find_run(x, counts[:200, 0].tolist())
        tail_x = np.array(x[start:], dtype=float)
        tail_y = demand_at_syncs(sim, 2, syncs[start:])  # paired by SYNC, not by recording index
        planned = counts[:, :2].astype(float)
        for point in np.column_stack([tail_x[-50:], tail_y[-50:]]):
            # The stop interpolates between planned rows, so it rests anywhere on a segment:
            # measure to the polyline, not to its vertices (up to half a 140-count row away).
            assert distance_to_polyline(point, planned) <= 1.0  # set-points are rounded to counts
        steps = np.abs(np.diff(tail_x[-60:]))
        assert steps[-1] <= 1  # came to rest


def test_heartbeat_loss_is_reported_and_stops_the_axes():
    with rig() as (master, sim, _):
        job = master.stream(sine_counts(3000))
        wait_for(lambda: (master.status().job_index or 0) > 50)
        sim.inject(FaultInjection("heartbeat_stop", node_id=3))
        result = job.wait(WAIT_S)
        assert result.outcome == "faulted"
        beat = [f for f in result.faults if f.kind == "heartbeat"]
        assert beat and beat[0].node_id == 3 and "no heartbeat" in beat[0].message
        wait_for(lambda: master.status().phase == "disabled")  # the master's phase runs ahead of the wire
        wait_for(lambda: all(sim[n].state is not State.OPERATION_ENABLED for n in (1, 2)))


@pytest.mark.parametrize("kind", ["stall", "following_error"])
def test_following_error_quick_stops(kind):
    with rig() as (master, sim, _):
        job = master.stream(sine_counts(2000, amplitude=50000))
        wait_for(lambda: (master.status().job_index or 0) > 50)
        sim.inject(FaultInjection(kind, node_id=1))
        result = job.wait(WAIT_S)
        assert result.outcome == "faulted"
        fe = [f for f in result.faults if f.kind == "following_error"]
        assert fe and fe[0].node_id == 1 and fe[0].axis == "X"
        wait_for(lambda: master.status().phase == "disabled")


def test_sdo_abort_during_bring_up_names_node_step_and_code():
    with rig(bring_up=False) as (master, sim, _):
        sim.inject(FaultInjection("sdo_abort", node_id=2, index=0x6060, code=0x0609_0030))
        with pytest.raises(FieldbusError) as info:
            master.bring_up()
        text = str(info.value)
        assert text.startswith("node 2: bring-up step 'set mode': SDO abort")
        assert "0x06090030" in text and "\n" not in text
        assert master.faults()[-1].kind == "bringup"


def test_missing_node_at_start_up_is_named():
    with rig(n_axes=3, simulated=2, bring_up=False) as (master, _, _):
        with pytest.raises(FieldbusError, match=r"^node 3: bring-up step 'boot-up': no boot-up message"):
            master.bring_up()


def test_identity_check_passes_for_the_configured_drive():
    with rig(identity=", identity: {vendor_id: 0x1234, product_code: 0x42}") as (master, _, _):
        assert master.status().phase == "holding"


def test_identity_mismatch_is_refused():
    with rig(bring_up=False, identity=", identity: {vendor_id: 0x1234, product_code: 0x43}") as (master, _, _):
        with pytest.raises(FieldbusError, match=r"^node 1: bring-up step 'identity check': drive reports vendor "
                           r".* axis X expects vendor 0x00001234 product 0x00000043$"):
            master.bring_up()


def test_tpdo_of_wrong_length_is_counted_and_never_used_as_position():
    with rig() as (master, _, probe):
        before = master.status().axes[0].position_counts
        probe.send(can.Message(arbitration_id=0x181, data=bytes([0x27, 0x06, 0x40]), is_extended_id=False))
        wait_for(lambda: master.status().axes[0].bad_tpdo_count == 1)
        cycle = master.status().cycle
        wait_for(lambda: master.status().cycle > cycle + 3)
        status = master.status()
        assert status.axes[0].position_counts == before
        assert status.phase == "holding" and not status.faults


def test_request_stop_then_reset_and_new_job():
    counts = sine_counts(2000, amplitude=20000)
    with rig("ip") as (master, sim, _):
        job = master.stream(counts)
        wait_for(lambda: (master.status().job_index or 0) > 100)
        job.request_stop()
        result = job.wait(WAIT_S)
        assert result.outcome == "stopped" and not result.faults and result.sent < len(counts)
        held = [a.setpoint_counts for a in master.status().axes]
        back = np.linspace(held, [0, 0, 0], 200).round().astype(np.int32)
        assert master.stream(back).wait(WAIT_S).outcome == "done"


def test_abort_quick_stops_and_reset_faults_re_enables():
    with rig() as (master, sim, _):
        job = master.stream(sine_counts(2000))
        wait_for(lambda: (master.status().job_index or 0) > 50)
        job.abort()
        assert job.wait(WAIT_S).outcome == "aborted"
        wait_for(lambda: master.status().phase == "disabled")
        with pytest.raises(FieldbusError, match="not holding"):
            master.stream(sine_counts(10))
        master.reset_faults()
        assert master.status().phase == "holding"
        assert all(sim[n].state is State.OPERATION_ENABLED for n in (1, 2, 3))


def test_reset_faults_after_a_drive_fault():
    with rig() as (master, sim, _):
        job = master.stream(sine_counts(2000))
        wait_for(lambda: (master.status().job_index or 0) > 50)
        sim.inject(FaultInjection("fault", node_id=1))
        assert job.wait(WAIT_S).outcome == "faulted"
        wait_for(lambda: master.status().phase == "disabled")
        master.reset_faults()
        held = [a.setpoint_counts for a in master.status().axes]
        assert master.stream(np.array([held] * 20, dtype=np.int32)).wait(WAIT_S).outcome == "done"


def test_job_far_from_the_held_position_is_refused_before_motion():
    with rig() as (master, _, _):
        far = sine_counts(10) + 100_000
        with pytest.raises(InputError, match="axis X: the job starts at"):
            master.stream(far)
        assert master.status().phase == "holding"


def test_traffic_log_records_sync_rpdo_and_tpdo(tmp_path):
    path = tmp_path / "bus.log"
    with rig(traffic_log=str(path)) as (master, _, _):
        assert master.stream(sine_counts(200)).wait(WAIT_S).outcome == "done"
    text = path.read_text()
    assert " 080#" in text and " 201#" in text and " 181#" in text and " 000#" in text


def rpdo_setpoints(path, node_id: int) -> list[int]:
    """Set-points (int32 after the controlword) of the RPDO frames of one node in a log file."""
    cob_id = 0x200 + node_id
    return [int.from_bytes(m.data[2:6], "little", signed=True)
            for m in can.LogReader(str(path)) if m.arbitration_id == cob_id and not m.is_rx]


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_one_traffic_log_per_job(tmp_path, suffix):
    first, second = sine_counts(120), sine_counts(80) // 2
    with rig() as (master, _, _):
        master.record_traffic(tmp_path / f"job1{suffix}")
        assert master.stream(first).wait(WAIT_S).outcome == "done"
        master.record_traffic(None)
        wait_for(lambda: master.status().phase == "holding")
        master.record_traffic(tmp_path / f"job2{suffix}")
        assert master.stream(second).wait(WAIT_S).outcome == "done"
        master.record_traffic(None)
    for name, job in (("job1", first), ("job2", second)):
        sent = rpdo_setpoints(tmp_path / f"{name}{suffix}", 1)
        # The job's set-points appear once each, in order, inside the file (held before/after).
        text = ",".join(map(str, sent))
        assert ",".join(map(str, job[:, 0].tolist())) in text, name
        frames = list(can.LogReader(str(tmp_path / f"{name}{suffix}")))
        assert any(m.arbitration_id == 0x80 for m in frames) and any(m.arbitration_id == 0x181 for m in frames)


def test_drive_that_never_answers_sync_is_named_with_step_and_state():
    with rig(bring_up=False) as (master, sim, _):
        sim.inject(FaultInjection("ignore_sync", node_id=2))
        with pytest.raises(FieldbusError) as info:
            master.bring_up()
        text = str(info.value)
        assert text.startswith("node 2: bring-up step 'shutdown': no TPDO1 received")
        assert "SWITCH ON DISABLED" in text and "after" in text and "\n" not in text
        assert master.faults()[-1].kind == "bringup" and master.faults()[-1].node_id == 2


def test_an_enable_phase_that_runs_out_of_time_says_so_not_only_the_step():
    """A drive still short of OPERATION ENABLED when the whole phase's time-out runs out (a
    slow drive, not one stuck in a state for the step time-out): the line says which limit."""
    with rig(bring_up=False, stuck_timeout_s=5.0, enable_timeout_s=0.3) as (master, sim, _):
        sim.inject(FaultInjection("ignore_sync", node_id=2))
        with pytest.raises(FieldbusError) as info:
            master.bring_up()
        text = str(info.value)
        assert text.startswith("node 2: bring-up step 'shutdown': no TPDO1 received")
        assert text.endswith("when the drives' enable time-out of 0.3 s ran out") and "\n" not in text


class FlakyBus(VirtualBus):
    """A virtual bus whose sends fail once ``failing`` is set (a cable pulled, bus-off)."""

    failing = False

    def send(self, msg, timeout=None):
        if self.failing:
            raise can.CanOperationError("simulated bus-off")
        super().send(msg, timeout)


def test_send_failure_is_a_bus_error_and_stops_the_job():
    channel = "fb-" + uuid.uuid4().hex
    with SimNetwork(channel=channel) as sim:
        for node in (1, 2, 3):
            sim.add_drive(node)
        bus = FlakyBus(channel=channel)
        master = Master(make_config(channel), bus)
        try:
            master.bring_up()
            job = master.stream(sine_counts(2000))
            wait_for(lambda: (master.status().job_index or 0) > 50)
            bus.failing = True
            result = job.wait(WAIT_S)
            assert result.outcome == "faulted"
            assert [(f.node_id, f.kind) for f in result.faults][:1] == [(None, "bus_error")]
            assert "simulated bus-off" in result.faults[0].message
            assert master.status().timing.send_errors >= 1
            wait_for(lambda: master.status().phase == "disabled")
        finally:
            bus.failing = False
            master.shutdown()
            bus.shutdown()


def test_half_playback_rate_plays_every_row_and_the_midpoints_between():
    """set_rate(0.5) before a job: the drives get every planned row on every other cycle and
    the midpoint between consecutive rows in between (the feed override's playback)."""
    counts = sine_counts(n=120, n_axes=1)
    with rig(n_axes=1) as (master, sim, _):
        master.set_rate(0.5)
        result = master.stream(counts).wait(WAIT_S)
        assert result is not None and result.outcome == "done"
        wait_for(lambda: len(sim[1].recorder) > 0 and recorded(sim, 1)[1][-1] == counts[-1, 0])
        rows = counts[:, 0].astype(float)
        between = np.round((rows[:-1] + rows[1:]) / 2.0)
        expected = np.empty(2 * len(rows) - 1)
        expected[0::2], expected[1::2] = rows, between
        _, setpoints = recorded(sim, 1)
        assert find_run(setpoints, expected.astype(int).tolist()) >= 0


def recorded_rows(sim: SimNetwork, n_axes: int) -> np.ndarray:
    columns = [recorded(sim, n)[1] for n in range(1, n_axes + 1)]
    n = min(len(c) for c in columns)
    return np.array([c[:n] for c in columns]).T


def test_hold_rests_on_the_path_and_resume_finishes_the_same_job():
    from nurbsmotion.service.verify import on_planned_path

    counts = sine_counts(n=1500, n_axes=2)
    with rig(n_axes=2) as (master, sim, _):
        job = master.stream(counts)
        wait_for(lambda: (master.status().job_index or 0) > 300)
        job.hold()
        wait_for(lambda: master.status().phase == "held")
        held_at = master.status().job_index
        cycle = master.status().cycle
        wait_for(lambda: master.status().cycle > cycle + 30)
        status = master.status()
        assert status.phase == "held" and not job.done() and status.job_index == held_at
        assert held_at < len(counts) - 1
        positions = [a.position_counts for a in status.axes]
        wait_for(lambda: master.status().cycle > status.cycle + 10)
        assert [a.position_counts for a in master.status().axes] == positions  # at rest
        job.resume()
        result = job.wait(WAIT_S)
        assert result is not None and result.outcome == "done" and result.sent == len(counts)
        wait_for(lambda: recorded_rows(sim, 2)[-1].tolist() == counts[-1].tolist())
        rows = recorded_rows(sim, 2)
        start = next(i for i in range(len(rows)) if rows[i].tolist() != rows[0].tolist()) - 1
        assert on_planned_path(rows[start:], counts)
        assert find_run(rows[:, 0].tolist(), counts[-200:, 0].tolist()) >= 0  # exact rows again after the resume


def test_pause_rows_hold_there_until_resume_and_every_row_is_applied_once():
    from nurbsmotion.service.verify import plan_with_holds

    counts = sine_counts(n=300, n_axes=2)
    counts[100:110] = counts[100]  # at rest around the pause rows, as the planner's exact stop gives
    counts[200:210] = counts[200]
    with rig(n_axes=2) as (master, sim, _):
        job = master.stream(counts, pauses=(105, 205))
        for row in (105, 205):
            wait_for(lambda: master.status().phase == "held" and master.status().job_index == row)
            cycle = master.status().cycle
            wait_for(lambda: master.status().cycle > cycle + 20)
            assert master.status().job_index == row and not job.done()
            job.resume()
            wait_for(lambda: master.status().phase != "held" or job.done())
        result = job.wait(WAIT_S)
        assert result is not None and result.outcome == "done"
        wait_for(lambda: recorded_rows(sim, 2)[-1].tolist() == counts[-1].tolist())
        assert plan_with_holds(recorded_rows(sim, 2), counts)
