"""Host side, beside a test run: log each 100 ms window in which a CPU lost >= 20 ms to steal
(the hypervisor ran something else on it) and each time this sampler itself woke > 60 ms late
(the host's CPUs were taken), with UTC times to set beside `cycle_thread_late` lines of the
vcan lane (docs/reliability.md, "Flakes").

Usage: ``nohup nice -n -5 python benchmarks/host_steal_watch.py /tmp/steal.log &`` (stop it
with kill). Steal is /proc/stat's eighth CPU field, in clock ticks.
"""

from __future__ import annotations

import argparse
import datetime
import os
import time

WINDOW_S = 0.1
STEAL_REPORT_MS = 20
SAMPLE_S = 0.01
LATE_S = 0.06


def steal_ticks() -> dict[str, int]:
    """Steal ticks so far per CPU (``cpu0``, ``cpu1``, ...)."""
    ticks: dict[str, int] = {}
    with open("/proc/stat") as f:
        for line in f:
            if line.startswith("cpu") and line[3] != " ":
                fields = line.split()
                ticks[fields[0]] = int(fields[8])
    return ticks


def utc_now() -> str:
    return f"{datetime.datetime.now(datetime.timezone.utc):%H:%M:%S.%f}"


def watch(path: str) -> None:
    ms_per_tick = 1000 // os.sysconf("SC_CLK_TCK")
    window_start, window_t = steal_ticks(), time.monotonic()
    previous_t = window_t
    with open(path, "a", buffering=1) as log:
        while True:
            time.sleep(SAMPLE_S)
            now = time.monotonic()
            if now - previous_t > LATE_S:
                log.write(f"{utc_now()} sampler_late gap_ms={1e3 * (now - previous_t):.0f}\n")
            previous_t = now
            if now - window_t < WINDOW_S:
                continue
            current = steal_ticks()
            steal_ms = {cpu: (current[cpu] - window_start.get(cpu, 0)) * ms_per_tick for cpu in current}
            if max(steal_ms.values(), default=0) >= STEAL_REPORT_MS:
                log.write(f"{utc_now()} steal_ms {steal_ms} window_ms={1e3 * (now - window_t):.0f}\n")
            window_start, window_t = current, now


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", help="file the lines are appended to")
    watch(parser.parse_args().log)


if __name__ == "__main__":
    main()
