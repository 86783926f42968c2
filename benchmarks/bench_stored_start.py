"""The daemon's side of a streamed start of a long program, without drives: what `start NAME`
and `run FILE` cost before the first chunk now that the checked program is mapped from the
store (issue 25 items 4 and 7), measurable on a host too loaded for simulated drives to keep
their heartbeats (bench_library_start.py's end-to-end rows need them).

One fresh process per size holds the daemon's side: a PlannerWorker (its own process, as in the
daemon), the checked-program store and, for a large program, the checker process
(service.program_check), with bench_first_motion's machine (T = 1 ms, J = 50000, 1 um chord
error, spindle, tools 1-99). For the program (a real CAM program repeated, in a file as the
library keeps it, passed as ``start NAME`` passes it: linked into the spool with its SHA-256,
never read in this process, service.program_file):

1. ``check``: prepare_streamed_job of the program not in the store (read and checked by the
   worker, or, from 4,000,000 characters, by the checker process first), seconds to the first
   chunk planned;
2. ``start`` x 3: the same from the store (the request without the text, the entry mapped by
   the worker and by this process), seconds to the first chunk planned (the best and the
   worst), this thread's CPU seconds, and the peak memory (VmHWM, reset before each start) of
   this process and of the worker.

First motion adds the record's creation and the master's start (and a spindle's spin-up).
Run: python benchmarks/bench_stored_start.py [--copies 2 19 190] [--program FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_first_motion import CONFIG, PROGRAM_MACHINE, TOOLS_YAML, load_line  # noqa: E402
from benchmarks.bench_library_start import (PROGRAM, TARGET_DAEMON_MB, TARGET_WORKER_MB, peak_mb,  # noqa: E402
                                            reset_peak, write_copies)

STARTS = 3


def one_size(program: Path, copies: int) -> dict[str, Any]:
    """The check and STARTS starts of ``program`` x ``copies`` (module docstring)."""
    import numpy as np

    from nurbsmotion.config import parse_config
    from nurbsmotion.service.checked_store import CheckedStore
    from nurbsmotion.service.planner_worker import PlannerWorker
    from nurbsmotion.service.program_check import ProgramChecker
    from nurbsmotion.service.program_file import file_stamp, snapshot
    from nurbsmotion.service.streamed_job import prepare_streamed_job

    work = Path(tempfile.mkdtemp(prefix="stored-"))
    (work / "tools.yaml").write_text(TOOLS_YAML)
    config = parse_config(CONFIG.format(channel="none", socket=work / "ctl.sock", data_dir=work / "var",
                                        extra=PROGRAM_MACHINE), str(work / "machine.yaml"), base_dir=work)
    name = f"{program.stem}_x{copies}{program.suffix}"
    path = work / name
    write_copies(program, copies, path)  # not in this process (bench_library_start.write_copies)
    store, checker, worker = CheckedStore.for_config(config), ProgramChecker(), PlannerWorker()
    worker.start()
    worker.wait_ready()

    recorded: list[Any] = []  # the library's record of the file: its stamp and SHA-256, once known

    def started() -> dict[str, Any]:
        reset_peak(os.getpid(), worker.pid)
        t0, cpu0 = time.perf_counter(), time.thread_time()
        text = snapshot(path, config.data_dir, *recorded)  # as the library's program is passed for `start NAME`
        recorded[:] = [file_stamp(path), text.sha256]
        job = prepare_streamed_job(name, text, config, worker, np.zeros(3), None, store=store, checker=checker)
        text.discard()
        seconds, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
        peaks = (peak_mb("self"), peak_mb(worker.pid))
        from_store = job.summary["checked_from_store"]
        blocks = len(job.program.blocks)
        job.cancel()
        job.wait_closed()
        return {"s": seconds, "cpu_s": cpu, "from_store": from_store, "blocks": blocks, "daemon_mb": peaks[0],
                "worker_mb": peaks[1]}

    try:
        check = started()
        starts = [started() for _ in range(STARTS)]
    finally:
        worker.close()
        checker.close()
    return {"program": program.name, "copies": copies, "lines": path.read_text().count("\n"), "blocks": check["blocks"],
            "check": check, "starts": starts}


def run_child(program: Path, copies: int) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    began = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    before = load_line()
    out = subprocess.run([sys.executable, __file__, "--child", str(copies), "--program", str(program)],
                         capture_output=True, text=True, env=env, timeout=3600)
    run = {"started": began, "load_before": before, "load_after": load_line()}
    if out.returncode != 0:
        tail = out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed"
        return {"program": program.name, "copies": copies, "error": tail, **run}
    return {**json.loads(out.stdout.strip().splitlines()[-1]), **run}


def table(results: list[dict[str, Any]]) -> str:
    rows = ["| program | lines (blocks) | not stored: s to the first chunk (read + check) | from the store: s to the "
            "first chunk, best - worst of 3 | this thread's CPU s | peak MB, this process / worker | "
            f"daemon < {TARGET_DAEMON_MB:g} MB, worker < {TARGET_WORKER_MB:g} MB | started, load before → after |",
            "|---|---|---|---|---|---|---|---|"]
    for r in results:
        head = f"| {r['program']} x {r['copies']} "
        if "error" in r:
            rows.append(f"{head}| failed: {r['error']} | | | | | | {r['started']}, {r['load_before']} |")
            continue
        starts = r["starts"]
        seconds = sorted(s["s"] for s in starts)
        daemon, worker = max(s["daemon_mb"] for s in starts), max(s["worker_mb"] for s in starts)
        stored = all(s["from_store"] for s in starts) and not r["check"]["from_store"]
        rows.append(f"{head}| {r['lines']:,} ({r['blocks']:,}) | {r['check']['s']:.2f} "
                    f"| {seconds[0]:.2f} - {seconds[-1]:.2f}{'' if stored else ' (NOT from the store)'} "
                    f"| {max(s['cpu_s'] for s in starts):.3f} | {daemon:.0f} / {worker:.0f} "
                    f"| {'met' if daemon < TARGET_DAEMON_MB else 'NOT met'}, "
                    f"{'met' if worker < TARGET_WORKER_MB else 'NOT met'} "
                    f"| {r['started']}, {r['load_before']} → {r['load_after']} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, nargs="*", default=[2, 19, 190])
    parser.add_argument("--program", type=Path, default=PROGRAM)
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(one_size(args.program, args.child)))
        return
    results = []
    for copies in args.copies:
        results.append(run_child(args.program, copies))
        print(json.dumps(results[-1]), flush=True)
    body = ("The daemon's side of a streamed start without drives (module docstring of the script): a planner worker "
            "process, the checked-program store and the checker process, bench_first_motion's machine. Seconds from "
            "the request (the program's file linked into the spool, as `start NAME` passes it: its text never read here) to the first chunk planned; first "
            "motion adds the job record and the master's start (and a spindle's spin-up). Peak memory: VmHWM of "
            "this process (the daemon's side, without the master and simulated drives) and of the planner worker, "
            "reset before each start. Host: 2 cores shared with other sessions (load average before → after).\n\n"
            + table(results))
    write_section("stored_start", "Starts from the checked-program store: the daemon's side (no drives)", body,
                  "python benchmarks/bench_stored_start.py --copies " + " ".join(str(c) for c in args.copies))


if __name__ == "__main__":
    main()
