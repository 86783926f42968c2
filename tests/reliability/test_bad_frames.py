"""Bad frames on the bus, injected with a raw python-can bus on the same virtual channel and
with the simulated drives' fault injection: TPDOs of the wrong length, frames with unknown
COB-IDs, SDO aborts and time-outs during bring-up, two devices with one node id, an EMCY
storm. Each gives a clear one-line report (or none, for frames that are not ours), nothing
crashes, and bad feedback never moves an axis."""

from __future__ import annotations

import random
import threading

import can
import numpy as np
import pytest

from nurbsmotion.can.cia402 import State
from nurbsmotion.errors import FieldbusError
from nurbsmotion.sim import FaultInjection, SimNetwork
from tests.reliability.rig import PERIOD_MS, WAIT_S, Rig, assert_no_jump, held_counts, rig, smooth_move
from tests.helpers import wait_for

NODES = (1, 2, 3)


def frame(can_id: int, data: bytes = b"", extended: bool = False, remote: bool = False) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=extended, is_remote_frame=remote,
                       dlc=len(data) if not remote else 0)


def applied_plan_exactly(r: Rig, counts: np.ndarray) -> bool:
    """Every drive's recording holds the planned column as one contiguous run at
    consecutive SYNCs (nothing lost, repeated or altered)."""
    for node in NODES:
        records = r.sim[node].recorder.as_array()
        planned = counts[:, node - 1]
        hits = np.flatnonzero(records[:, 2] == planned[0])
        if not any(len(records) >= s + len(planned) and np.array_equal(records[s:s + len(planned), 2], planned)
                   and np.all(np.diff(records[s:s + len(planned), 0]) == 1) for s in hits):
            return False
    return True


def stream_while(r: Rig, counts: np.ndarray, disturb) -> object:
    """Stream ``counts`` and call ``disturb()`` once the job is a fifth in; the job's result."""
    for drive in r.sim.drives.values():
        drive.recorder.clear()
    job = r.master.stream(counts)
    wait_for(lambda: (r.master.status().job_index or 0) > len(counts) // 5 or job.done(), what="the job to run")
    disturb()
    result = job.wait(WAIT_S)
    assert result is not None
    wait_for(lambda: all(len(r.sim[n].recorder) and r.sim[n].recorder.as_array()[-1, 2] == counts[-1, n - 1]
                         for n in NODES) or result.outcome != "done", what="the drives to apply the last row")
    return result


def test_tpdos_of_the_wrong_length_are_counted_and_never_used(caplog):
    rng = random.Random(1)
    with rig() as r:
        counts = smooth_move(held_counts(r.master), [10.0, -8.0, 6.0], duration_s=0.6)

        def garbage_tpdos() -> None:
            for _ in range(60):
                node = rng.choice(NODES)
                length = rng.choice([0, 1, 2, 3, 4, 5, 7, 8])
                r.probe.send(frame(0x180 + node, bytes(rng.getrandbits(8) for _ in range(length))))

        result = stream_while(r, counts, garbage_tpdos)
        assert result.outcome == "done" and not result.faults
        assert applied_plan_exactly(r, counts)
        status = r.master.status()
        assert sum(a.bad_tpdo_count for a in status.axes) == 60
        wait_for(lambda: [a.position_counts for a in r.master.status().axes] ==
                 [r.sim[n].position_actual for n in NODES] == counts[-1].tolist(), what="positions from good TPDOs")
        warnings = [rec.getMessage() for rec in caplog.records if "bad_tpdo_length" in rec.getMessage()]
        assert 1 <= len(warnings) <= 3  # logged once per node, not per frame


def test_bad_feedback_while_disabled_does_not_move_an_axis_at_re_enable():
    with rig() as r:
        job = r.master.stream(smooth_move(held_counts(r.master), [10.0, 10.0, 10.0], duration_s=0.6))
        wait_for(lambda: (r.master.status().job_index or 0) > 40, what="the job to run")
        job.abort()
        wait_for(lambda: r.master.status().phase == "disabled", what="quick stop")
        at_rest = [r.sim[n].position_actual for n in NODES]
        for node in NODES:  # short frames carrying a far 'position' while the master follows feedback
            r.probe.send(frame(0x180 + node, bytes([0x27, 0x02, 0x00, 0x00, 0x10])))
        wait_for(lambda: all(a.bad_tpdo_count >= 1 for a in r.master.status().axes), what="the bad TPDOs")
        for drive in r.sim.drives.values():
            drive.recorder.clear()
        r.master.reset_faults()
        assert held_counts(r.master) == at_rest == [r.sim[n].position_actual for n in NODES]
        assert_no_jump(r.sim, list(NODES), PERIOD_MS / 1000)


def test_frames_with_unknown_cob_ids_change_nothing():
    rng = random.Random(2)
    foreign_nodes = list(range(10, 128))  # ids of nodes that are not configured (ours are 1-3)
    functions = [0x080, 0x180, 0x200, 0x280, 0x300, 0x380, 0x400, 0x480, 0x500, 0x580, 0x600, 0x700]
    with rig() as r:
        counts = smooth_move(held_counts(r.master), [-6.0, 9.0, -4.0], duration_s=0.6)

        def foreign_frames() -> None:
            for _ in range(300):
                kind = rng.randrange(4)
                data = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 8)))
                if kind == 0:
                    r.probe.send(frame(rng.choice(functions) + rng.choice(foreign_nodes), data))
                elif kind == 1:
                    r.probe.send(frame(rng.getrandbits(29), data, extended=True))
                elif kind == 2:
                    r.probe.send(frame(rng.choice([0x7E4, 0x7E5, 0x7FF, 0x001, 0x07F]), data))
                else:  # remote frames, also for our own TPDO ids
                    r.probe.send(frame(rng.choice([0x181, 0x182, 0x183, 0x701]), remote=True))

        result = stream_while(r, counts, foreign_frames)
        assert result.outcome == "done" and not result.faults, result
        assert applied_plan_exactly(r, counts)
        status = r.master.status()
        assert status.phase == "holding" and not status.faults
        assert all(a.bad_tpdo_count == 0 and a.emcy_count == 0 for a in status.axes)


@pytest.mark.parametrize("index, step", [(0x6060, "set mode"), (0x1600, "RPDO1"), (0x1A00, "TPDO1"),
                                         (0x6065, "set following error window"),
                                         (0x1017, "set heartbeat producer")])
def test_an_sdo_abort_in_any_bring_up_step_is_one_line_and_enables_nothing(index, step):
    with rig(bring_up=False) as r:
        r.sim.inject(FaultInjection("sdo_abort", node_id=2, index=index, code=0x0800_0020))
        with pytest.raises(FieldbusError) as info:
            r.master.bring_up()
        text = str(info.value)
        assert text.startswith("node 2: bring-up step '") and step in text and "\n" not in text
        assert "0x08000020" in text and f"0x{index:04X}" in text
        assert all(d.state is not State.OPERATION_ENABLED for d in r.sim.drives.values())
        r.sim[2].clear_injections()
        r.master.bring_up()  # the cause removed, a second bring-up works
        assert r.master.status().phase == "holding"


def test_a_node_that_boots_but_never_answers_sdo_is_named():
    with rig(n_drives=2, bring_up=False) as r:
        stop = threading.Event()

        def mute_node_3() -> None:  # answers NMT reset with a boot-up message, then nothing
            while not stop.is_set():
                msg = r.probe.recv(0.05)
                if msg is not None and msg.arbitration_id == 0 and len(msg.data) == 2 and msg.data[1] in (0, 3):
                    r.probe.send(frame(0x703, b"\x00"))

        thread = threading.Thread(target=mute_node_3)
        thread.start()
        try:
            with pytest.raises(FieldbusError, match=r"^node 3: bring-up step '[^']+': no SDO answer [^\n]*$"):
                r.master.bring_up()
        finally:
            stop.set()
            thread.join(WAIT_S)
        assert all(d.state is not State.OPERATION_ENABLED for d in r.sim.drives.values())


def test_two_devices_with_the_same_node_id_are_refused_at_bring_up():
    with rig(bring_up=False) as r:
        twin = SimNetwork(channel=r.config.bus.channel)
        twin.add_drive(2)
        twin.start()
        try:
            with pytest.raises(FieldbusError, match=r"^node 2: bring-up step 'boot-up': .*same node id"):
                r.master.bring_up()
            assert twin[2].state is not State.OPERATION_ENABLED
        finally:
            twin.stop()
        assert all(d.state is not State.OPERATION_ENABLED for d in r.sim.drives.values())


def test_an_emcy_storm_is_reported_once_and_the_master_keeps_cycling():
    with rig() as r:
        counts = smooth_move(held_counts(r.master), [12.0, 12.0, -12.0], duration_s=0.6)

        def storm() -> None:
            for k in range(3000):
                code = 0x4210 + k % 7
                r.probe.send(frame(0x82, bytes([code & 0xFF, code >> 8, 0x08, 0, 0, 0, 0, 0])))

        result = stream_while(r, counts, storm)
        assert result.outcome == "faulted"
        reports = [f for f in result.faults if f.kind == "emcy"]
        assert len(reports) == 1 and reports[0].node_id == 2 and "EMCY 0x42" in reports[0].message
        wait_for(lambda: r.master.status().axes[1].emcy_count == 3000, what="every EMCY counted")
        cycle = r.master.status().cycle
        wait_for(lambda: r.master.status().cycle > cycle + 20, what="the loop to keep cycling")
        assert_no_jump(r.sim, list(NODES), PERIOD_MS / 1000)  # the controlled stop stays within the limits
        r.master.reset_faults()
        back = smooth_move(held_counts(r.master), [1.0, 1.0, 1.0], duration_s=0.1)
        assert r.master.stream(back).wait(WAIT_S).outcome == "done"
