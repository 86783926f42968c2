"""What the host did with a User-Mode Linux guest's processes while the daemon's cycle thread
was away (docs/vcan.md, "The vcan lane and the host's scheduler").

A UML guest runs its kernel as one host process and each guest process (the daemon, the
drives' ``nurbsmotion sim``, pytest, the planner worker) as a host process of its own. This
runs a command (e.g. the vcan Wang test through scripts/with-vcan), samples every
``linux.uml`` host process's /proc/PID/schedstat (CPU run, time waiting for a CPU) and state
every few ms, then, for each ``cycle_thread_late`` line the daemons wrote meanwhile
(daemon.log files under /tmp/nm-*/, as tests/integration/daemon_helpers writes them), prints
what each of those host processes did in that window:

    python benchmarks/uml_host_sched.py -- scripts/with-vcan .venv/bin/python -m pytest -q \\
        tests/vcan/test_daemon_on_vcan.py::test_wang_table1_runs_to_completion_and_the_drives_applied_the_plan

A process that was runnable (state R) for most of the window but ran a few ms was left
waiting by the host's scheduler. (schedstat's run_delay grows only when a waiting task gets
the CPU, so a wait still going on at the window's end shows in the states, not the delay.)
"""

from __future__ import annotations

import argparse
import collections
import datetime
import glob
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

SAMPLE_S = 0.002
LATE = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) .*cycle_thread_late (.*)$")
Sample = tuple[float, int, int, int, str]  # time, pid, run_ns, run_delay_ns, state


def uml_pids() -> list[int]:
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                if Path(f"/proc/{entry}/comm").read_text().strip() == "linux.uml":
                    pids.append(int(entry))
            except OSError:
                continue
    return pids


def sample(pid: int, now: float) -> Sample | None:
    try:
        run, delay, _ = map(int, Path(f"/proc/{pid}/schedstat").read_text().split())
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, ValueError):
        return None
    return now, pid, run, delay, state


def sampler(samples: list[Sample], stop: threading.Event) -> None:
    pids: list[int] = []
    refreshed = 0.0
    while not stop.is_set():
        now = time.time()
        if now - refreshed > 0.5:
            pids, refreshed = uml_pids(), now
        for pid in pids:
            s = sample(pid, now)
            if s is not None:
                samples.append(s)
        time.sleep(SAMPLE_S)


def late_lines(since: float) -> list[tuple[float, float, str]]:
    """(end time, away seconds, fields) of every cycle_thread_late line written since ``since``."""
    found = []
    for path in glob.glob("/tmp/nm-*/daemon.log"):
        if os.path.getmtime(path) < since:
            continue
        for line in Path(path).read_text(errors="replace").splitlines():
            m = LATE.match(line)
            if m:
                end = datetime.datetime.strptime(m.group(1), "%Y-%m-%d %H:%M:%S").timestamp() + int(m.group(2)) / 1e3
                away = float(re.search(r"away_ms=([\d.]+)", m.group(3)).group(1)) / 1e3  # type: ignore[union-attr]
                found.append((end, away, m.group(3)))
    return sorted(found)


def report(samples: list[Sample], windows: list[tuple[float, float, str]]) -> None:
    by_pid: dict[int, list[Sample]] = collections.defaultdict(list)
    for s in samples:
        by_pid[s[1]].append(s)
    for end, away, fields in windows:
        print(f"cycle_thread_late {fields}")
        for pid, rows in sorted(by_pid.items()):
            inside = [r for r in rows if end - away <= r[0] <= end]
            if len(inside) < 2:
                continue
            ran_ms = (inside[-1][2] - inside[0][2]) / 1e6
            waited_ms = (inside[-1][3] - inside[0][3]) / 1e6
            states = collections.Counter(r[4] for r in inside)
            runnable = states.get("R", 0) / len(inside)
            if ran_ms > 2 or waited_ms > 2 or runnable > 0.2:
                print(f"  host pid {pid}: ran {ran_ms:.0f} ms, waited for a CPU {waited_ms:.0f} ms, "
                      f"runnable in {runnable:.0%} of {len(inside)} samples over {away * 1e3:.0f} ms")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARGS...]")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command to run after --")
    samples: list[Sample] = []
    stop = threading.Event()
    thread = threading.Thread(target=sampler, args=(samples, stop), daemon=True)
    started = time.time()
    thread.start()
    try:
        rc = subprocess.call(command)
    finally:
        stop.set()
        thread.join(1.0)
    report(samples, late_lines(started))
    return rc


if __name__ == "__main__":
    sys.exit(main())
