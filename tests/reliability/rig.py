"""A master and simulated drives on a private virtual bus, a probe bus for raw frames, smooth
test moves and the checks the reliability tests share.

Every wait polls with a generous time-out (a loaded 2-core machine must not make a test
flaky); nothing asserts on timing except where the issue asks for a detection bound.
"""

from __future__ import annotations

import contextlib
import uuid
from typing import Any, Iterator

import numpy as np

from nurbsmotion.config import MachineConfig, parse_config
from nurbsmotion.fieldbus import Master
from nurbsmotion.sim import SimNetwork
from tests.helpers import SimulatedMachine, simulated_machine

WAIT_S = 30.0
PERIOD_MS = 4
HEARTBEAT_PRODUCER_MS = 100
HEARTBEAT_CONSUMER_MS = 250  # < 3 producer periods: loss is detected within three heartbeats, and a
# machine stall of up to 250 ms (seen on the shared 2-core container) is not taken for a lost drive
V_MAX_MM_S = 100.0
A_MAX_MM_S2 = 2000.0
COUNTS_PER_MM = 1000
MODES = ("csp", "csp", "ip")


def machine_config(channel: str, period_ms: float = PERIOD_MS, n_axes: int = 3) -> MachineConfig:
    """Three axes (CSP, CSP, IP) with v_max/a_max set, on ``channel`` of the virtual bus."""
    axes = "".join(
        f"  - {{name: {'XYZ'[i]}, node_id: {i + 1}, mode: {MODES[i]}, counts_per_mm: {COUNTS_PER_MM},"
        f" max_velocity_mm_s: {V_MAX_MM_S}, max_accel_mm_s2: {A_MAX_MM_S2}, following_error_window_mm: 2.0,"
        f" quick_stop_decel: {int(A_MAX_MM_S2 * COUNTS_PER_MM)}}}\n"  # 0x6085: the simulated servo's unit is counts/s²
        for i in range(n_axes))
    text = (f"cycle_period_ms: {period_ms}\nbus: {{interface: virtual, channel: {channel}}}\n"
            f"monitoring: {{heartbeat_producer_ms: {HEARTBEAT_PRODUCER_MS},"
            f" heartbeat_consumer_ms: {HEARTBEAT_CONSUMER_MS}}}\n"
            f"interpolation: {{max_accel_mm_s2: {A_MAX_MM_S2}}}\naxes:\n{axes}")
    return parse_config(text, "reliability.yaml")


Rig = SimulatedMachine  # config, master, sim, probe


@contextlib.contextmanager
def rig(n_drives: int = 3, bring_up: bool = True, period_ms: float = PERIOD_MS, **master_kw: Any) -> Iterator[Rig]:
    """Drives 1..n_drives and a master for three axes; torn down whatever happens."""
    master_kw.setdefault("rt_priority", None)  # SCHED_FIFO would starve the in-process drives on 2 loaded cores
    config = machine_config("rel-" + uuid.uuid4().hex, period_ms)
    with simulated_machine(config, {node: {"lag_cycles": 1} for node in range(1, n_drives + 1)}, bring_up,
                           **master_kw) as machine:
        yield machine


def smooth_move(start_counts: list[int], distance_mm: list[float], duration_s: float,
                period_s: float = PERIOD_MS / 1000) -> np.ndarray:
    """Rest-to-rest move x(t) = x0 + D/2·(1 - cos(π t/τ)): peak speed π D/(2τ), peak
    acceleration π² D/(2τ²); (N, n_axes) int32 counts, one row per cycle."""
    n = int(round(duration_s / period_s)) + 1
    phase = 0.5 * (1.0 - np.cos(np.pi * np.arange(n) / (n - 1)))
    moves = np.outer(phase, np.asarray(distance_mm) * COUNTS_PER_MM)
    return (np.asarray(start_counts)[None, :] + np.round(moves)).astype(np.int32)


def held_counts(master: Master) -> list[int]:
    return [a.setpoint_counts for a in master.status().axes]


def demand_per_sync(records: np.ndarray) -> np.ndarray:
    """The demand a drive followed at every SYNC from its first to its last recorded
    set-point: a SYNC without a new set-point keeps the previous demand (docs/sim.md)."""
    syncs, setpoints = records[:, 0], records[:, 2]
    if len(syncs) == 0:
        return setpoints.astype(float)
    filled = np.empty(syncs[-1] - syncs[0] + 1)
    index = syncs - syncs[0]
    filled[:] = np.nan
    filled[index] = setpoints
    valid = ~np.isnan(filled)
    last = np.maximum.accumulate(np.where(valid, np.arange(len(filled)), 0))
    return filled[last]


def worst_steps(demand_counts: np.ndarray, period_s: float, counts_per_mm: float = COUNTS_PER_MM) -> tuple[float, float]:
    """(max |Δ|/T in mm/s, max |Δ²|/T² in mm/s²) of one drive's per-SYNC demand."""
    mm = demand_counts / counts_per_mm
    v = np.abs(np.diff(mm)) / period_s if len(mm) > 1 else np.zeros(1)
    a = np.abs(np.diff(mm, n=2)) / period_s**2 if len(mm) > 2 else np.zeros(1)
    return float(v.max(initial=0.0)), float(a.max(initial=0.0))


def assert_records_within_limits(records: dict[int, np.ndarray], period_s: float, v_max_mm_s: float = V_MAX_MM_S,
                                 a_max_mm_s2: float = A_MAX_MM_S2, counts_per_mm: float = COUNTS_PER_MM,
                                 tol: float = 0.02) -> None:
    """Every drive's applied set-points (recorder rows per node) stay within v_max and a_max
    (+ tol and one count of rounding per difference): no jump, also not while stopping."""
    count_mm = 1.0 / counts_per_mm
    for node, rows in records.items():
        v, a = worst_steps(demand_per_sync(rows), period_s, counts_per_mm)
        assert v <= v_max_mm_s * (1 + tol) + count_mm / period_s, f"node {node}: set-point step {v:.1f} mm/s"
        assert a <= a_max_mm_s2 * (1 + tol) + 2 * count_mm / period_s**2, f"node {node}: {a:.0f} mm/s² step"


def assert_no_jump(sim: SimNetwork, nodes: list[int], period_s: float) -> None:
    """assert_records_within_limits for the live recordings of ``nodes``."""
    assert_records_within_limits({n: sim[n].recorder.as_array() for n in nodes}, period_s)
