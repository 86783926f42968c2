"""What one more subscriber costs the daemon's status publisher (service.subscriptions), by
itself: the publisher's CPU time per round (one status line and one event to every
subscriber, each written to its own Unix socket pair) with 0, 1, 10 and 30 subscribers.

    python benchmarks/bench_publisher.py --rounds 2000 [--write]

The publisher thread is the daemon's only thread that does work per subscriber; every
microsecond it runs holds the interpreter lock the cycle thread needs. The status is the
shape of a three-axis daemon's answer, with the positions and the cycle count changing each
round as during a job. CPU time is the publisher's own thread time (time.thread_time), so a
loaded host stretches the wall time but not this figure much.
"""

from __future__ import annotations

import argparse
import itertools
import selectors
import socket
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402
from nurbsmotion.service.subscriptions import StatusHub  # noqa: E402


def status_at(tick: int) -> dict[str, Any]:
    """A three-axis status whose positions and cycle count move every tick."""
    axes = [{"name": name, "node_id": i + 1, "commanded_mm": round(0.01 * tick + i, 4),
             "actual_mm": round(0.01 * tick + i - 0.002, 4), "following_error_mm": 0.002, "statusword": 4663,
             "state": "OPERATION_ENABLED", "mode": "csp", "homed": True, "soft_limits_mm": [-500.0, 500.0],
             "fault": None} for i, name in enumerate("XYZ")]
    return {"ok": True, "state": "running", "phase": "streaming", "job": {"id": "1d6fa14b", "name": "part.nc",
            "line": 10 + tick // 50, "progress": tick / 1e5}, "axes": axes,
            "cycles": {"count": 1000 * tick, "late": 3, "missed": 0, "period_ms": 1.0},
            "override": {"requested_percent": 100, "effective_percent": 100}, "spindle": "stopped", "coolant": "off",
            "homing": {"busy": False, "error": None}, "faults": [], "queue": {"entries": [], "paused": False}}


class Drain:
    """Reads and discards every subscriber socket's far end (its own thread)."""

    def __init__(self) -> None:
        self.selector = selectors.DefaultSelector()
        self.stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)

    def add(self, sock: socket.socket) -> None:
        self.selector.register(sock, selectors.EVENT_READ)

    def _run(self) -> None:
        while not self.stop:
            for key, _ in self.selector.select(0.05):
                key.fileobj.recv(1 << 20)  # type: ignore[union-attr]


def cpu_per_round_us(subscribers: int, rounds: int) -> float:
    """The publisher's thread CPU time per round (µs), median of five blocks."""
    ticks = itertools.count()
    current = {"status": status_at(0)}
    hub = StatusHub(lambda: current["status"], publisher_thread=False)
    drain = Drain()
    pairs = []
    for _ in range(subscribers):
        near, far = socket.socketpair()
        near.setblocking(False)
        sub, _ = hub.subscribe(max_hz=100.0)
        sub.attach(near.send)
        sub.next_status_s = 0.0
        drain.add(far)
        pairs.append((near, far, sub))
    drain.thread.start()
    blocks = []
    for _ in range(5):
        start = time.thread_time()
        for _ in range(rounds // 5):
            tick = next(ticks)
            current["status"] = status_at(tick)
            hub.publish_event({"event": "override_changed", "level": "INFO", "fields": {"requested_percent": 100},
                               "line": "override_changed requested_percent=100", "logged_t": time.time()})
            for _, _, sub in pairs:
                sub.next_status_s = 0.0  # every subscriber due: one status line each round
            hub.publish_once()
        blocks.append((time.thread_time() - start) / (rounds // 5) * 1e6)
    drain.stop = True
    drain.thread.join()
    dropped = sum(sub.dropped is not None for _, _, sub in pairs)
    for near, far, sub in pairs:
        hub.unsubscribe(sub)
        near.close()
        far.close()
    if dropped:
        raise RuntimeError(f"{dropped} subscribers dropped: the drain fell behind")
    return statistics.median(blocks)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2000)
    parser.add_argument("--counts", default="0,1,10,30")
    parser.add_argument("--write", action="store_true", help="rewrite its section of docs/benchmarks.md")
    args = parser.parse_args()
    counts = [int(c) for c in args.counts.split(",")]
    results = {n: cpu_per_round_us(n, args.rounds) for n in counts}
    load = " / ".join(Path("/proc/loadavg").read_text().split()[:3])
    rows = ["| subscribers | publisher CPU per round us | each further subscriber us |", "|---|---|---|"]
    previous: tuple[int, float] | None = None
    for n, us in results.items():
        extra = (us - previous[1]) / (n - previous[0]) if previous is not None and n > previous[0] else float("nan")
        rows.append(f"| {n} | {us:.0f} | {extra:.1f} |")
        previous = (n, us)
    body = (f"The daemon's status publisher (service.subscriptions) by itself: one status line and one event to "
            f"every subscriber a round, each written to its own Unix socket pair (read by a drain thread), "
            f"{args.rounds} rounds, median of five blocks of the publisher thread's CPU time. The status is a "
            f"three-axis daemon's, moving every round. Load average at the end: {load}.\n\n" + "\n".join(rows) + "\n")
    if args.write:
        write_section("publisher", "Status publisher: what one more subscriber costs", body,
                      f"python benchmarks/bench_publisher.py --rounds {args.rounds} --write")
    else:
        print(body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
