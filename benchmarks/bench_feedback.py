"""What recording a job's feedback.csv costs the cycle loop: the master streams jobs to three
simulated drives at T = 1 ms (the soak's setup, benchmarks/bench_soak.py), alternating jobs
without and with the service's FeedbackLog (Master.record_feedback + a flush every second by
another thread, as the daemon's job watcher does), the lines formatted in that thread (as
before 2026-11-29) or in the cycle thread's slack (as the daemon does now,
fieldbus.cycle_slack); figures per mode: late and missed cycles, rows written, the flush's
time as the flushing thread sees it.

    PYTHONPATH=src python benchmarks/bench_feedback.py --jobs 10
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_soak import COUNTS_PER_MM, MOVE_MM, MOVE_S, move, run_as_hardware, three_axes  # noqa: E402

from nurbsmotion.fieldbus import Master  # noqa: E402
from nurbsmotion.fieldbus.cycle_slack import CycleSlack  # noqa: E402
from nurbsmotion.service.feedback import FeedbackLog  # noqa: E402

WITHOUT = "without feedback.csv"
IN_THREAD = "feedback.csv formatted in the flushing thread"
IN_SLACK = "feedback.csv formatted in the cycle thread's slack"
MODES = (WITHOUT, IN_THREAD, IN_SLACK)


def run_job(master: Master, distance: np.ndarray, period_s: float, folder: Path | None,
            slack: CycleSlack | None = None) -> tuple[int, float]:
    """One job; with ``folder``: recorded to feedback.csv there, formatted in ``slack`` if
    given. (rows written, flush seconds)"""
    log = FeedbackLog(folder / "feedback.csv", master.axis_map) if folder is not None else None
    if log is not None:
        master.record_feedback(log.add)
    start = np.array([a.setpoint_counts for a in master.status().axes])
    job = master.stream(move(start, distance, period_s))
    flush_s = 0.0
    while job.wait(1.0) is None:
        if log is not None and job.start_cycle >= 0:
            t0 = time.perf_counter()
            log.flush(job.start_cycle, slack)
            flush_s += time.perf_counter() - t0
    if log is None:
        return 0, 0.0
    master.record_feedback(None)
    t0 = time.perf_counter()
    log.close(max(job.start_cycle, 0), slack)
    return log.rows, flush_s + time.perf_counter() - t0


def measure(jobs: int, period_ms: float) -> dict[str, dict[str, float]]:
    figures = {m: {"jobs": 0, "cycles": 0, "late": 0, "missed": 0, "rows": 0, "flush_s": 0.0, "motion_s": 0.0}
               for m in MODES}
    distance = np.array(MOVE_MM) * COUNTS_PER_MM
    with three_axes(period_ms, "feedback") as master, tempfile.TemporaryDirectory() as tmp:
        for k in range(len(MODES) * jobs):
            mode = MODES[k % len(MODES)]
            before = master.status().timing
            t0 = time.monotonic()
            rows, flush_s = run_job(master, distance, master.config.cycle_period_s,
                                    Path(tmp) if mode != WITHOUT else None,
                                    master.cycle_slack if mode == IN_SLACK else None)
            after = master.status().timing
            distance = -distance
            f = figures[mode]
            f["jobs"] += 1
            f["cycles"] += after.cycles - before.cycles
            f["late"] += after.late_cycles - before.late_cycles
            f["missed"] += after.missed_cycles - before.missed_cycles
            f["rows"] += rows
            f["flush_s"] += flush_s
            f["motion_s"] += time.monotonic() - t0
            if master.status().faults:
                master.reset_faults()
    return figures


def report(figures: dict[str, dict[str, float]], period_ms: float, load: tuple[float, float]) -> str:
    rows = []
    for mode in MODES:
        f = figures[mode]
        cycles = max(f["cycles"], 1)
        rows.append(f"| {mode} | {f['jobs']:.0f} | {f['cycles']:.0f} | {f['late']:.0f} "
                    f"({100.0 * f['late'] / cycles:.2f} %) | {f['missed']:.0f} ({100.0 * f['missed'] / cycles:.3f} %) | "
                    f"{f['rows']:.0f} | {1e3 * f['flush_s'] / max(f['motion_s'], 1e-9):.1f} ms/s |")
    return f"""Master + three simulated drives (X, Y CSP, Z IP) in one process on the virtual bus,
T = {period_ms:g} ms; jobs ({MOVE_S:g} s moves) alternate without and with the job's feedback.csv
(every TPDO1 through Master.record_feedback into service.feedback.FeedbackLog, flushed once a
second by another thread, its lines formatted there or in the cycle thread's slack). Load average before / after: {load[0]:.2f} / {load[1]:.2f} (other work
shares the 2 cores: compare the rows of one run, not runs).

| mode | jobs | cycles | late | missed | rows | flush time per second of motion |
| --- | --- | --- | --- | --- | --- | --- |
{chr(10).join(rows)}
"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=10, help="jobs per mode")
    parser.add_argument("--period-ms", type=float, default=1.0)
    parser.add_argument("--sim-priority", type=int, default=10)
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    args = parser.parse_args()
    run_as_hardware(args.sim_priority)
    load_before = os.getloadavg()[0]
    figures = measure(args.jobs, args.period_ms)
    body = report(figures, args.period_ms, (load_before, os.getloadavg()[0]))
    if args.no_write:
        print(body)
    else:
        write_section("feedback", f"Feedback recording (T = {args.period_ms:g} ms, three axes)", body,
                      f"PYTHONPATH=src python benchmarks/bench_feedback.py --jobs {args.jobs}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
