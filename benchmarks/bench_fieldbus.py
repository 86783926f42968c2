"""Fieldbus streaming benchmark: cycle lateness, missed cycles and CPU of the master.

Simulated drives (nurbsmotion.sim) on python-can's virtual bus in the same process; a
smooth synthetic path is streamed for --seconds. Lateness = time the SYNC left after its
deadline. CPU is measured per thread from /proc/self/task/<tid>/stat: the master's cycle
thread plus its receive (notifier) thread, and the whole process (incl. the drives).

    PYTHONPATH=src python benchmarks/bench_fieldbus.py --seconds 10
    PYTHONPATH=src python benchmarks/bench_fieldbus.py --seconds 60 --cases 3x1,3x4,6x4,6x1
"""

from __future__ import annotations

import argparse
import os
import threading
import time
import uuid

import can
import numpy as np

from nurbsmotion.config import parse_config
from nurbsmotion.fieldbus import Master
from nurbsmotion.sim import SimNetwork

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def thread_cpu_s(native_id: int) -> float:
    """utime + stime of one thread of this process, seconds."""
    with open(f"/proc/self/task/{native_id}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def master_thread_ids(master: Master) -> list[int]:
    threads = [master._thread]
    notifier = master._network.notifier if master._network else None
    threads += list(getattr(notifier, "_readers", []))
    return [t.native_id for t in threads if isinstance(t, threading.Thread) and t.native_id]


def run_case(n_axes: int, period_ms: float, seconds: float, gc_mode: str = "freeze") -> dict[str, float]:
    channel = "bench" + uuid.uuid4().hex
    axes = "".join(f"  - {{name: A{i}, node_id: {i + 1}, mode: csp}}\n" for i in range(n_axes))
    config = parse_config(f"cycle_period_ms: {period_ms}\nbus: {{interface: virtual, channel: {channel}}}\n"
                          f"monitoring: {{max_bus_load: 1.0}}\naxes:\n{axes}", "bench.yaml")
    n = int(seconds / config.cycle_period_s)
    k = np.arange(n)
    path = (20000 * np.sin(2 * np.pi * k / max(n, 2))).astype(np.int32)
    counts = np.column_stack([path] * n_axes)
    with SimNetwork(channel=channel) as sim:
        for i in range(n_axes):
            sim.add_drive(i + 1)
        bus = can.Bus(interface="virtual", channel=channel)
        # the virtual bus has no bitrate: 6 axes at 1 ms exceed 1 Mbit/s, measured anyway
        master = Master(config, bus, check_load=False, gc_mode=gc_mode)
        try:
            master.bring_up()
            tids = master_thread_ids(master)
            cpu0 = sum(thread_cpu_s(t) for t in tids)
            proc0, wall0 = time.process_time(), time.perf_counter()
            stats0 = master.status().timing
            job = master.stream(counts)
            result = job.wait(seconds * 3 + 10)
            wall = time.perf_counter() - wall0
            cpu = sum(thread_cpu_s(t) for t in tids) - cpu0
            proc = time.process_time() - proc0
            timing = master.status().timing
        finally:
            master.shutdown()
            bus.shutdown()
    return {
        "axes": n_axes, "period_ms": period_ms, "seconds": round(wall, 1),
        "cycles": timing.cycles - stats0.cycles, "outcome": result.outcome if result else "timeout",
        "p50_us": timing.lateness_p50_s * 1e6, "p99_us": timing.lateness_p99_s * 1e6,
        "max_us": timing.lateness_max_s * 1e6, "missed": timing.missed_cycles - stats0.missed_cycles,
        "late": timing.late_cycles - stats0.late_cycles,
        "master_cpu_pct": 100 * cpu / wall, "process_cpu_pct": 100 * proc / wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="streaming time per case (default 10)")
    parser.add_argument("--cases", default="3x1,3x4,6x4,6x1", help="AXESxPERIOD_MS list (default 3x1,3x4,6x4,6x1)")
    parser.add_argument("--gc", default="freeze", choices=("freeze", "disable", "none"), help="Master gc_mode")
    args = parser.parse_args()
    print(f"gc_mode={args.gc}, {os.cpu_count()} CPUs, SCHED_FIFO cycle thread if permitted")
    print("| axes | T ms | s | cycles | outcome | p50 µs | p99 µs | max µs | late | missed | master CPU % | process CPU % |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for case in args.cases.split(","):
        n_axes, period = case.split("x")
        r = run_case(int(n_axes), float(period), args.seconds, args.gc)
        print(f"| {r['axes']} | {r['period_ms']:g} | {r['seconds']} | {r['cycles']} | {r['outcome']} | "
              f"{r['p50_us']:.0f} | {r['p99_us']:.0f} | {r['max_us']:.0f} | {r['late']} | {r['missed']} | "
              f"{r['master_cpu_pct']:.1f} | {r['process_cpu_pct']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
