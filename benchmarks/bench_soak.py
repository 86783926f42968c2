"""Soak: the master streams jobs back to back to three simulated drives at T = 1 ms on
python-can's virtual bus (same process) for --seconds; figures: missed and late cycles,
lateness, faults, and the process' resident memory sampled every --sample-s seconds.

    PYTHONPATH=src python benchmarks/bench_soak.py --seconds 60          # the benchmark suite
    PYTHONPATH=src python benchmarks/bench_soak.py --seconds 3600        # the one-hour soak

Each job is a rest-to-rest move of every axis (x = D/2·(1 - cos(π t/τ)), 2 s) and back; the
drives record nothing (a recording grows 40 B per set-point by design). Memory is flat when
the RSS at the end is within a few MB of the RSS after the first jobs (allocator warm-up).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import can
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402

from nurbsmotion.config import parse_config  # noqa: E402
from nurbsmotion.fieldbus import Master  # noqa: E402
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY  # noqa: E402
from nurbsmotion.sim import SimNetwork  # noqa: E402

COUNTS_PER_MM = 1000
MOVE_MM = (40.0, -30.0, 20.0)
MOVE_S = 2.0


def rss_mb() -> float:
    """Resident set size of this process (VmRSS), MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def move(start: np.ndarray, distance_counts: np.ndarray, period_s: float) -> np.ndarray:
    """(N, 3) int32 rest-to-rest cosine move from ``start`` by ``distance_counts``."""
    n = int(round(MOVE_S / period_s)) + 1
    phase = 0.5 * (1.0 - np.cos(np.pi * np.arange(n) / (n - 1)))
    return (start[None, :] + np.round(np.outer(phase, distance_counts))).astype(np.int32)


@dataclass
class SoakResult:
    seconds: float
    period_ms: float
    jobs: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)
    cycles: int = 0
    missed: int = 0
    late: int = 0
    late_threshold_ms: float = 0.0
    p50_ms: float = 0.0
    p99_ms: float = 0.0
    max_ms: float = 0.0
    faults: list[str] = field(default_factory=list)
    rss_mb: list[tuple[float, float]] = field(default_factory=list)  # (elapsed s, MB)
    load_before: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_after: tuple[float, float, float] = (0.0, 0.0, 0.0)
    drive_threads: str = "normal priority"


def run_as_hardware(priority: int) -> str:
    """SCHED_FIFO ``priority`` for this process' threads from now on (the simulated drives
    stand in for hardware: a drive thread preempted while holding the GIL would stall the
    master, which real drives cannot do), as benchmarks/bench_fieldbus.py does."""
    if priority <= 0:
        return "normal priority"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f"SCHED_FIFO {priority}"
    except (PermissionError, OSError):
        return "normal priority (no permission for SCHED_FIFO)"


@contextmanager
def three_axes(period_ms: float, name: str) -> Iterator[Master]:
    """A brought-up Master and three simulated drives (X, Y CSP, Z IP; recording nothing) on
    a private virtual bus; everything stopped afterwards."""
    channel = f"{name}-{uuid.uuid4().hex}"
    axes = "".join(f"  - {{name: {axis}, node_id: {i + 1}, mode: {mode}, counts_per_mm: {COUNTS_PER_MM}}}\n"
                   for i, (axis, mode) in enumerate((("X", "csp"), ("Y", "csp"), ("Z", "ip"))))
    config = parse_config(f"cycle_period_ms: {period_ms}\nbus: {{interface: virtual, channel: {channel}}}\n"
                          f"axes:\n{axes}", f"{name}.yaml")
    sim = SimNetwork(channel=channel)
    for node in (1, 2, 3):
        sim.add_drive(node, record=False)
    sim.start()
    bus = can.Bus(interface="virtual", channel=channel)
    master = Master(config, bus, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze")  # as the daemon runs it
    try:
        master.bring_up()
        yield master
    finally:
        master.shutdown()
        bus.shutdown()
        sim.stop()


def soak(seconds: float, period_ms: float = 1.0, sample_s: float = 2.0) -> SoakResult:
    result = SoakResult(seconds, period_ms, load_before=os.getloadavg())
    with three_axes(period_ms, "soak") as master:
        config = master.config
        distance = np.array(MOVE_MM) * COUNTS_PER_MM
        t0 = time.monotonic()
        next_sample = t0
        while time.monotonic() - t0 < seconds:
            start = np.array([a.setpoint_counts for a in master.status().axes])
            job = master.stream(move(start, distance, config.cycle_period_s))
            distance = -distance
            while (outcome := job.wait(0.2)) is None:
                next_sample = _sample(result, t0, next_sample, sample_s)
            next_sample = _sample(result, t0, next_sample, sample_s)
            result.jobs += 1
            result.outcomes[outcome.outcome] = result.outcomes.get(outcome.outcome, 0) + 1
            if outcome.outcome != "done":
                master.reset_faults()
        result.rss_mb.append((time.monotonic() - t0, rss_mb()))
        status = master.status()
        t = status.timing
        result.cycles, result.missed, result.late = t.cycles, t.missed_cycles, t.late_cycles
        result.late_threshold_ms = t.late_threshold_s * 1e3
        result.p50_ms, result.p99_ms, result.max_ms = t.lateness_p50_s * 1e3, t.lateness_p99_s * 1e3, \
            t.lateness_max_s * 1e3
        result.faults = [str(f) for f in status.faults]
    result.load_after = os.getloadavg()
    return result


def _sample(result: SoakResult, t0: float, next_sample: float, sample_s: float) -> float:
    now = time.monotonic()
    if now >= next_sample:
        result.rss_mb.append((now - t0, rss_mb()))
        return next_sample + sample_s
    return next_sample


def report(r: SoakResult) -> str:
    rss = np.array([mb for _, mb in r.rss_mb])
    warm = rss[min(len(rss) - 1, max(1, len(rss) // 10))]  # after the first tenth: allocator warm-up
    faults = "; ".join(r.faults[:5]) if r.faults else "none"
    return f"""Master + three simulated drives (X, Y CSP, Z IP) in one process on the virtual bus,
T = {r.period_ms:g} ms, jobs streamed back to back for {r.seconds:g} s (each a {MOVE_S:g} s move and back).
Simulated drives' threads: {r.drive_threads}; the master's cycle thread SCHED_FIFO 20, its receive thread 19.
Load average of the machine (other work on the 2 cores) before / after: {r.load_before[0]:.2f} / {r.load_after[0]:.2f}.

| figure | value |
| --- | --- |
| jobs (outcomes) | {r.jobs} ({', '.join(f'{k} {v}' for k, v in sorted(r.outcomes.items()))}) |
| cycles | {r.cycles} |
| missed cycles (lateness > T) | {r.missed} |
| late cycles (lateness > {r.late_threshold_ms:.2f} ms) | {r.late} ({100.0 * r.late / max(r.cycles, 1):.2f} %) |
| lateness p50 / p99 / max | {r.p50_ms:.3f} / {r.p99_ms:.3f} / {r.max_ms:.2f} ms |
| faults | {faults} |
| RSS start / after warm-up / end / max | {rss[0]:.1f} / {warm:.1f} / {rss[-1]:.1f} / {rss.max():.1f} MB ({len(rss)} samples) |
| RSS growth after warm-up | {rss[-1] - warm:+.2f} MB |
"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--period-ms", type=float, default=1.0)
    parser.add_argument("--sample-s", type=float, default=2.0)
    parser.add_argument("--sim-priority", type=int, default=10,
                        help="SCHED_FIFO priority of the simulated drives' threads (0: normal)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    args = parser.parse_args()
    drive_threads = run_as_hardware(args.sim_priority)
    result = soak(args.seconds, args.period_ms, args.sample_s)
    result.drive_threads = drive_threads
    body = report(result)
    command = f"PYTHONPATH=src python benchmarks/bench_soak.py --seconds {args.seconds:g} --sim-priority {args.sim_priority}"
    if args.no_write:
        print(body)
    else:
        write_section("soak", f"Soak ({args.seconds:g} s at T = {args.period_ms:g} ms, three axes)", body, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
