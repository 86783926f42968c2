"""Fieldbus streaming benchmark: cycle lateness, missed cycles and CPU of the master.

Simulated drives (nurbsmotion.sim) on python-can's virtual bus in the same process; a
smooth synthetic path is streamed for --seconds. Lateness = time the SYNC left after its
deadline. CPU is measured per thread from /proc/self/task/<tid>/stat: the master's cycle
thread plus its receive (notifier) thread, and the whole process (incl. the drives).

    PYTHONPATH=src python benchmarks/bench_fieldbus.py --seconds 10
    PYTHONPATH=src python benchmarks/bench_fieldbus.py --seconds 60 --cases 3x1,3x4,6x4,6x1

The first row (0 axes) is the bare deadline loop in a SCHED_FIFO thread with no bus: the
lateness the machine itself allows (virtual machines and other load show up there).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
import uuid
from pathlib import Path

import can
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402

from nurbsmotion.config import parse_config  # noqa: E402
from nurbsmotion.fieldbus import Master  # noqa: E402
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY  # noqa: E402
from nurbsmotion.fieldbus.cycle import DeadlineGrid, LatenessStats, wait_until  # noqa: E402
from nurbsmotion.sim import SimNetwork  # noqa: E402

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
        master = Master(config, bus, check_load=False, gc_mode=gc_mode, rt_priority=CYCLE_THREAD_PRIORITY)
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


def baseline_timing(period_ms: float, seconds: float) -> dict[str, float]:
    """The same deadline loop with no bus and no Python threads: what the machine itself allows."""
    stats = LatenessStats(late_threshold_s=0.1 * period_ms / 1000.0)
    grid = DeadlineGrid(period_ms / 1000.0, time.perf_counter() + period_ms / 1000.0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(20))
    except PermissionError:
        pass
    proc0, wall0 = time.process_time(), time.perf_counter()
    for _ in range(int(seconds * 1000 / period_ms)):
        lateness, missed = grid.advance(wait_until(grid.next_s, 60e-6))
        stats.add(lateness, missed)
    wall = time.perf_counter() - wall0
    return {"axes": 0, "period_ms": period_ms, "seconds": round(wall, 1), "cycles": stats.count,
            "outcome": "baseline", "p50_us": stats.percentile_s(0.5) * 1e6, "p99_us": stats.percentile_s(0.99) * 1e6,
            "max_us": stats.max_s * 1e6, "missed": stats.missed, "late": stats.late,
            "master_cpu_pct": 100 * (time.process_time() - proc0) / wall, "process_cpu_pct": float("nan")}


def row_text(r: dict[str, float]) -> str:
    return (f"| {r['axes']} | {r['period_ms']:g} | {r['seconds']} | {r['cycles']} | {r['outcome']} | "
            f"{r['p50_us']:.0f} | {r['p99_us']:.0f} | {r['max_us']:.0f} | {r['late']} | {r['missed']} | "
            f"{r['master_cpu_pct']:.1f} | {r['process_cpu_pct']:.1f} |")


def verdict(rows: list[dict[str, float]]) -> str:
    """The issue's target: 3 axes at 1 ms, p99 <= 100 µs, no missed cycle, master CPU <= 35 %."""
    target = [r for r in rows if r["axes"] == 3 and r["period_ms"] == 1]
    if not target:
        return "target case (3 axes at 1 ms) not run"
    r = target[0]
    checks = [("p99 <= 100 µs", r["p99_us"] <= 100), ("0 missed", r["missed"] == 0),
              ("master CPU <= 35 %", r["master_cpu_pct"] <= 35)]
    return "; ".join(f"{name}: {'met' if ok else 'NOT met'}" for name, ok in checks)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="streaming time per case (default 10)")
    parser.add_argument("--cases", default="3x1,3x4,6x4,6x1", help="AXESxPERIOD_MS list (default 3x1,3x4,6x4,6x1)")
    parser.add_argument("--gc", default="freeze", choices=("freeze", "disable", "none"), help="Master gc_mode")
    parser.add_argument("--sim-priority", type=int, default=10,
                        help="SCHED_FIFO priority for the simulated drives' threads (they stand in for hardware "
                             "that does not share this CPU or GIL); 0 = normal scheduling")
    parser.add_argument("--no-write", action="store_true", help="print only, do not rewrite docs/benchmarks.md")
    args = parser.parse_args()
    if args.sim_priority > 0:
        try:  # threads created from now on inherit it; the master raises its own threads above
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.sim_priority))
        except PermissionError:
            print("no permission for SCHED_FIFO: simulated drives run at normal priority")
    load_before = os.getloadavg()[0]
    header = ("| axes | T ms | s | cycles | outcome | p50 µs | p99 µs | max µs | late | missed | master CPU % "
              "| process CPU % |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    print(header)
    rows = []
    for case in ["0x1"] + args.cases.split(","):
        n_axes, period = case.split("x")
        if n_axes == "0":  # the timing loop alone, run in a thread like the master's
            out: list[dict[str, float]] = []
            worker = threading.Thread(target=lambda: out.append(baseline_timing(float(period), args.seconds)))
            worker.start()
            worker.join()
            r = out[0]
        else:
            r = run_case(int(n_axes), float(period), args.seconds, args.gc)
        rows.append(r)
        print(row_text(r), flush=True)
    body = "\n".join([
        f"Simulated CSP drives (nurbsmotion.sim) on python-can's virtual bus in the same process, threads at "
        f"SCHED_FIFO {args.sim_priority} (the master's cycle thread 20, its receive thread 19), gc_mode "
        f"{args.gc}. Load average (1 min) {load_before:.2f} before and {os.getloadavg()[0]:.2f} after: other "
        f"helpers share these 2 cores. Row 0 axes = the bare deadline loop with no bus (the machine's own "
        f"stalls). Lateness = SYNC sent after its deadline; late = more than 10 % of T; missed = more than "
        f"one period; master CPU = cycle + receive thread, process CPU includes the simulated drives.",
        "", header, *[row_text(r) for r in rows], "",
        f"Target (3 axes at 1 ms, {args.seconds:g} s): {verdict(rows)}. 6 axes at 1 ms exceed a real 1 Mbit/s "
        f"bus (the bus-load check refuses it); measured with the check off to show the master's own cost.",
    ])
    if not args.no_write:
        write_section("fieldbus", "Fieldbus streaming", body,
                      f"PYTHONPATH=src python benchmarks/bench_fieldbus.py --seconds {args.seconds:g}")


if __name__ == "__main__":
    main()
