"""Faults injected at random cycles of a job, for every fault kind of the simulated drives:
the job ends 'faulted' naming the node, every axis stops, no drive ever applied a set-point
step beyond v_max / a_max (also while stopping), and reset + a new job work.

Fast variant: SEEDS_FAST seeds per kind in the default run; ``pytest -m slow`` runs 20.
"""

from __future__ import annotations

import random

import can
import pytest

from nurbsmotion.sim import FaultInjection
from tests.reliability.rig import PERIOD_MS, WAIT_S, Rig, assert_no_jump, held_counts, rig, smooth_move
from tests.helpers import wait_for

SEEDS_FAST = 3
SEEDS_LONG = 20
FOREVER = 10**9
# kind -> fault kinds a report naming the injected node may have
EXPECTED = {
    "fault": {"emcy", "fault_bit"},
    "emcy_warning": {"emcy"},
    "heartbeat_stop": {"heartbeat", "following_error"},  # missing TPDO1 is often seen first
    "ignore_sync": {"following_error", "fault_bit", "heartbeat"},
    "following_error": {"following_error", "emcy"},
    "stall": {"following_error", "emcy"},
    "drop_rpdo": {"following_error"},
}
KINDS = list(EXPECTED)


def inject(r: Rig, kind: str, node: int) -> None:
    if kind == "emcy_warning":  # a warning EMCY (temperature) while the drive keeps running
        r.probe.send(can.Message(arbitration_id=0x80 + node, data=bytes([0x10, 0x42, 0x08, 0, 0, 0, 0, 0]),
                                 is_extended_id=False))
    elif kind in ("ignore_sync", "drop_rpdo"):
        r.sim.inject(FaultInjection(kind, node_id=node, count=FOREVER))
    else:
        r.sim.inject(FaultInjection(kind, node_id=node))


def recover(r: Rig) -> None:
    """What an operator does after the fault: power back on, clear the cause, reset."""
    for drive in r.sim.drives.values():
        drive.clear_injections()
        if drive.silent:
            drive.power_on()
    r.master.reset_faults()


def axes_at_rest(r: Rig, cycles: int = 10) -> bool:
    """Every powered drive's actual position is the same over ``cycles`` master cycles."""
    drives = [d for d in r.sim.drives.values() if not d.silent]
    before = [d.position_actual for d in drives]
    start = r.master.status().cycle
    wait_for(lambda: r.master.status().cycle >= start + cycles, what="master cycles")
    return [d.position_actual for d in drives] == before


def run_seed(r: Rig, kind: str, seed: int) -> None:
    rng = random.Random(f"{kind}-{seed}")
    node = rng.randint(1, 3)
    start = held_counts(r.master)
    sign = [1 if s <= 0 else -1 for s in start]  # move back towards 0: positions stay bounded
    distance = [sign[j] * rng.uniform(5.0, 15.0) for j in range(3)]
    counts = smooth_move(start, distance, duration_s=0.6)
    at = rng.randint(5, len(counts) // 2)  # the rest of the move (> 2.5 mm) exceeds the 2 mm window
    for drive in r.sim.drives.values():
        drive.recorder.clear()
    job = r.master.stream(counts)
    wait_for(lambda: (r.master.status().job_index or 0) >= at or job.done(), what=f"cycle {at} of the job")
    assert not job.done(), f"the job ended before the fault was injected: {job.result}"
    inject(r, kind, node)
    result = job.wait(WAIT_S)
    assert result is not None, "the job never ended"
    context = f"{kind} on node {node} at job cycle {at} (seed {seed})"
    assert result.outcome == "faulted", f"{context}: outcome {result.outcome}, faults {result.faults}"
    named = {f.kind for f in result.faults if f.node_id == node}
    assert named & EXPECTED[kind], f"{context}: reports {[str(f) for f in result.faults]}"
    assert all(f.message and "\n" not in f.message for f in result.faults)
    # quick_stop may last: a drive whose RPDOs are all lost never gets the quick-stop command (it holds still)
    wait_for(lambda: r.master.status().phase in ("holding", "disabled", "quick_stop"), what="the axes to stop")
    assert wait_for(lambda: axes_at_rest(r), what="every axis at rest"), context
    assert_no_jump(r.sim, [n for n in (1, 2, 3)], PERIOD_MS / 1000)
    recover(r)
    back = smooth_move(held_counts(r.master), [1.0, -1.0, 1.0], duration_s=0.1)
    assert r.master.stream(back).wait(WAIT_S).outcome == "done", f"{context}: no new job after reset"


def _run_kind(kind: str, seeds: range) -> None:
    with rig() as r:
        for seed in seeds:
            run_seed(r, kind, seed)


@pytest.mark.parametrize("kind", KINDS)
def test_a_fault_at_a_random_cycle_stops_every_axis_without_a_jump(kind):
    _run_kind(kind, range(SEEDS_FAST))


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
def test_a_fault_at_a_random_cycle_stops_every_axis_without_a_jump_20_seeds(kind):
    _run_kind(kind, range(SEEDS_LONG))
