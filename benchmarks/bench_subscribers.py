"""Subscribed clients against the cycle loop: missed and late cycles of a job at T = 1 ms with
0 and 10 clients subscribed (interleaved, same process and host), and the latency from a
logged event (``logged_t``) to each client's receipt of it (median, p99).

    python benchmarks/bench_subscribers.py --seconds 60 --rounds 2

The daemon runs in this process with simulated drives on python-can's virtual bus (as
``nurbsmotion demo``); the clients are threads of one other process (as the web gateway
will be), each reading its own Unix-socket connection. During each job the feed override is
set every 0.25 s, so each client receives a stream of ``override_changed`` events to time.
"""

from __future__ import annotations

import argparse
import multiprocessing
import statistics
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402

from nurbsmotion.config import load_config  # noqa: E402
from nurbsmotion.service.client import Client  # noqa: E402
from nurbsmotion.service.daemon import Daemon  # noqa: E402

CONFIG = """\
cycle_period_ms: 1
simulate: true
bus: {{interface: virtual, channel: {channel}}}
interpolation: {{algorithm: lookahead, feed_mm_min: 6000, chord_error_mm: 0.01, max_accel_mm_s2: 1000,
                max_jerk_mm_s3: 50000}}
axes:
  - {{name: X, node_id: 1, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-500, 500], max_velocity_mm_s: 200}}
  - {{name: Y, node_id: 2, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-500, 500], max_velocity_mm_s: 200}}
  - {{name: Z, node_id: 3, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-500, 500], max_velocity_mm_s: 200}}
monitoring: {{feedback_log: false}}
control: {{socket: {socket}}}
data_dir: {data_dir}
"""


class Receiver:
    """One subscribed client; notes the receipt time of every event line."""

    def __init__(self, socket_path: Path) -> None:
        self.client = Client(socket_path)
        self.stream = self.client.subscribe()
        next(self.stream)
        self.latencies_s: list[float] = []
        self.lines = 0
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            for line in self.stream:
                self.lines += 1
                if line.get("notify") == "event" and line.get("logged_t"):
                    self.latencies_s.append(time.time() - line["logged_t"])
        except Exception:  # noqa: BLE001 - the connection ends with the round
            pass

    def close(self) -> None:
        assert self.client._sock is not None
        self.client._sock.shutdown(2)
        self.thread.join(5.0)
        self.client.close()


def program_for(seconds: float) -> str:
    """Back and forth along X at 100 mm/s for about ``seconds``."""
    strokes = max(1, int(seconds * 100.0 / 100.0))
    moves = ["G21 G90", "G01 X0 F6000"]
    for i in range(strokes):
        moves.append(f"G01 X{100 if i % 2 == 0 else 0}")
    return "\n".join(moves) + "\n"


def receive_in_child(socket_path: str, subscribers: int, ready: Any, stop: Any, results: Any) -> None:
    """The clients' process: subscribe, read until told to stop, send back the figures."""
    receivers = [Receiver(Path(socket_path)) for _ in range(subscribers)]
    ready.set()
    stop.wait()
    for r in receivers:
        r.close()
    results.put((sum(r.lines for r in receivers), [x for r in receivers for x in r.latencies_s]))


def run_round(daemon: Daemon, subscribers: int, seconds: float) -> dict[str, Any]:
    socket_path = Path(daemon.config.control.socket)
    context = multiprocessing.get_context("spawn")
    ready, stop, results = context.Event(), context.Event(), context.Queue()
    child = context.Process(target=receive_in_child, args=(str(socket_path), subscribers, ready, stop, results))
    child.start()
    ready.wait(60.0)
    with Client(socket_path) as client:
        before = client.call("status")["cycles"]
        job = client.call("submit", name="bench.nc", program=program_for(seconds))["job"]["id"]
        percent = 100
        while client.call("status").get("job") is not None:
            time.sleep(0.25)
            percent = 101 if percent == 100 else 100
            client.call("override", percent=percent)
        after = client.call("status")["cycles"]
        outcome = client.call("job", id=job)["job"].get("outcome")
    stop.set()
    lines, latencies = results.get(timeout=60.0)
    child.join(10.0)
    latencies.sort()
    return {"subscribers": subscribers, "cycles": after["count"] - before["count"],
            "late": after["late"] - before["late"], "missed": after["missed"] - before["missed"],
            "outcome": outcome.get("outcome") if isinstance(outcome, dict) else outcome,
            "lines": lines,
            "median_ms": statistics.median(latencies) * 1e3 if latencies else float("nan"),
            "p99_ms": latencies[int(0.99 * (len(latencies) - 1))] * 1e3 if latencies else float("nan"),
            "events": len(latencies)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each job")
    parser.add_argument("--rounds", type=int, default=2, help="pairs of (0, 10 subscribers) jobs, interleaved")
    parser.add_argument("--subscribers", type=int, default=10)
    parser.add_argument("--no-write", action="store_true", help="print, do not rewrite docs/benchmarks.md")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="nm-bench-sub-"))
    path = folder / "machine.yaml"
    path.write_text(CONFIG.format(channel=f"bench-sub-{uuid.uuid4().hex}", socket=folder / "ctl.sock",
                                  data_dir=folder / "data"))
    daemon = Daemon(load_config(path))
    daemon.start()
    rows = []
    try:
        for _ in range(args.rounds):
            for n in (0, args.subscribers):
                rows.append(run_round(daemon, n, args.seconds))
                print(rows[-1], flush=True)
    finally:
        daemon.close()
    load = Path("/proc/loadavg").read_text().split()[:3]
    table = ["| round | subscribers | outcome | cycles | late (> 10 % T) | missed (> T) | lines received | events timed | "
             "event latency median ms | p99 ms |", "|---|---|---|---|---|---|---|---|---|---|"]
    for i, r in enumerate(rows):
        table.append(f"| {i // 2 + 1} | {r['subscribers']} | {r['outcome']} | {r['cycles']:,} | {r['late']} | {r['missed']} | "
                     f"{r['lines']:,} | {r['events']} | {r['median_ms']:.2f} | {r['p99_ms']:.2f} |")
    body = (f"Daemon with three simulated drives in one process (virtual bus), T = 1 ms, a {args.seconds:g} s job "
            f"per row, 0 and {args.subscribers} subscribed clients (threads of one other process) interleaved; "
            f"the override set every 0.25 s gives each client events to time (log record to receipt). "
            f"Load average at the end: {' / '.join(load)} (2 cores shared with other work: compare rows of "
            f"one run).\n\n" + "\n".join(table) + "\n")
    command = f"python benchmarks/bench_subscribers.py --seconds {args.seconds:g} --rounds {args.rounds}"
    if args.no_write:
        print(body)
    else:
        write_section("subscribers", "Subscribed clients against the cycle loop", body, command)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
