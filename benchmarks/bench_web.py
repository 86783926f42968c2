"""The web gateway as an operator meets it: the daemon and ``nurbsmotion web`` as separate
processes (simulated drives in the daemon, T = 1 ms), WebSocket clients in this process.

    python benchmarks/bench_web.py --seconds 60 --rounds 2
    python benchmarks/bench_web.py --seconds 20 --rounds 3 --previous-src /tmp/main/src  # before/after

Figures (issue 22's benchmarks):
- latency from a daemon event (its log record's time, ``logged_t``) to a WebSocket client's
  receipt, median and p99, with 1 and with 10 clients (the feed override is set every 0.25 s
  during a job, so each client gets a stream of ``override_changed`` events);
- late and missed cycles of a job with 0 clients, 10 WebSocket clients (the gateway holds one
  daemon subscription for all of them: web.fanout) and 10 direct ``subscribe`` connections on
  the daemon's control socket, interleaved round by round, with the daemon's CPU; with
  ``--clients-off-realtime-cpu`` also 10 WebSocket clients whose process keeps off the daemon's
  real-time CPU (the gateway does by itself: web.cpus);
- the gateway's CPU while idle (one client connected) and while a job streams to 10 clients;
- the console's time to parse and draw the preview of a 100,000-line program in headless
  Chromium (``window.previewDrawnMs``), when Debian's chromium and playwright are installed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import aiohttp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402

from nurbsmotion.runtime import cpu_split, thread_cpus  # noqa: E402
from nurbsmotion.service.client import Client  # noqa: E402

MACHINE = """\
cycle_period_ms: 1
simulate: true
bus: {{interface: virtual, channel: {channel}}}
interpolation: {{algorithm: lookahead, feed_mm_min: 6000, chord_error_mm: 0.01, max_accel_mm_s2: 1000,
                max_jerk_mm_s3: 50000}}
axes:
  - {{name: X, node_id: 1, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-500, 500], max_velocity_mm_s: 200}}
  - {{name: Y, node_id: 2, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-500, 500], max_velocity_mm_s: 200}}
  - {{name: Z, node_id: 3, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-500, 500], max_velocity_mm_s: 200}}
control: {{socket: {socket}}}
data_dir: {data_dir}
web: {{listen: "127.0.0.1:{port}"}}
"""


SRC = Path(__file__).resolve().parents[1] / "src"
SETTLE_S = 6.0  # between rounds: longer than the gateway's web.fanout.LINGER_S


def stop_process(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL if it has not ended in 20 s: a benchmark leaves no daemon behind."""
    proc.terminate()
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        print(f"pid {proc.pid} did not end in 20 s after SIGTERM: killed", file=sys.stderr)
        proc.kill()
        proc.wait(20)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def normal_thread_switches(pid: int) -> dict[int, int]:
    """Context switches (voluntary + not) of each of the process's SCHED_OTHER threads, by
    thread id: each is a wake-up of a thread that takes the interpreter lock at normal
    priority, where the real-time cycle thread may have to wait for it."""
    counts: dict[int, int] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            if int((task / "stat").read_text().rsplit(")", 1)[1].split()[38]) != 0:  # policy: SCHED_OTHER is 0
                continue
            fields = dict(line.split(":", 1) for line in (task / "status").read_text().splitlines() if ":" in line)
        except (FileNotFoundError, ProcessLookupError):
            continue  # a request's thread that just ended
        counts[int(task.name)] = int(fields["voluntary_ctxt_switches"]) + int(fields["nonvoluntary_ctxt_switches"])
    return counts


def switches_between(before: dict[int, int], after: dict[int, int]) -> int:
    """Switches of the threads that lived through the interval (a request's short thread is the
    same in every round and is left out)."""
    return sum(after[tid] - before[tid] for tid in before.keys() & after.keys())


def program_for(seconds: float) -> str:
    strokes = max(1, int(seconds))  # 100 mm at 100 mm/s: about a second each
    return "G21 G90\nG01 X0 F6000\n" + "".join(f"G01 X{100 if i % 2 == 0 else 0}\n" for i in range(strokes))


Latency = tuple[float, float]  # (event logged -> client, event logged -> the daemon's publisher sent it) s


def event_latency(line: dict[str, Any]) -> Latency | None:
    """The line's latency from the daemon's log record, and the daemon's part of it (the
    publisher stamps ``t`` when it sends); None for a line that is not a timed event."""
    if line.get("notify") != "event" or not line.get("logged_t"):
        return None
    return time.time() - line["logged_t"], line["t"] - line["logged_t"]


async def client(url: str, latencies: list[Latency], stop: asyncio.Event) -> None:
    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        while not stop.is_set():
            try:
                message = await asyncio.wait_for(ws.receive(), 0.2)
            except asyncio.TimeoutError:
                continue
            if message.type != aiohttp.WSMsgType.TEXT:
                return
            timed = event_latency(json.loads(message.data))
            if timed is not None:
                latencies.append(timed)


class DirectSubscriber:
    """One ``subscribe`` connection on the daemon's socket, read by its own thread, timing
    its events; ``close`` hangs up."""

    def __init__(self, socket_path: str, latencies: list[Latency]) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(socket_path)
        self.sock.sendall(b'{"cmd": "subscribe"}\n')
        self.latencies = latencies
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        with self.sock.makefile("rb") as stream:
            for raw in stream:
                timed = event_latency(json.loads(raw))
                if timed is not None:
                    self.latencies.append(timed)

    def close(self) -> None:
        self.sock.shutdown(socket.SHUT_RDWR)
        self.thread.join(5.0)
        self.sock.close()


def ready_cycles(c: Client) -> dict[str, Any]:
    """The cycle counters once the machine is idle without faults: after an earlier round's
    fault (its row says so) reset it first (a reset restarts the counters)."""
    for _ in range(5):
        status = c.call("status")
        if status["state"] == "idle" and not status.get("faults"):
            break
        c.request("reset")
        time.sleep(2.0)
    return dict(c.call("status")["cycles"])


def this_process_on(cpus: set[int]) -> None:
    """Every thread of this process (the clients, their event loop, the job's thread) on
    ``cpus``; threads started later inherit their starter's CPUs."""
    for task in Path("/proc/self/task").iterdir():
        try:
            os.sched_setaffinity(int(task.name), cpus)
        except OSError:  # the thread ended
            continue


def off_realtime_cpu() -> set[int]:
    """The CPUs but the daemon's real-time one (runtime.cpu_split), as an operator keeps
    browsers and other programs off an isolated real-time CPU (isolcpus)."""
    split = cpu_split(thread_cpus())
    return set(split.normal) if split is not None else thread_cpus()


async def job_round(ws_url: str, socket_path: str, clients: int, kind: str, seconds: float,
                    pids: dict[str, int], clients_cpus: set[int] | None = None) -> dict[str, Any]:
    """One job with ``clients`` of ``kind`` ("WebSocket" or "direct") connected; with
    ``clients_cpus``, this process's threads run on those CPUs for the job."""
    latencies: list[Latency] = []
    stop = asyncio.Event()
    await asyncio.sleep(SETTLE_S)  # the gateway closes its daemon subscription 5 s after the last client left
    everywhere = os.sched_getaffinity(0)
    if clients_cpus is not None:
        this_process_on(clients_cpus)
    tasks = [asyncio.create_task(client(ws_url, latencies, stop)) for _ in range(clients if kind == "WebSocket" else 0)]
    direct = [DirectSubscriber(socket_path, latencies) for _ in range(clients if kind == "direct" else 0)]
    await asyncio.sleep(1.0)

    def run_job() -> tuple[dict[str, Any], dict[str, Any], str]:
        with Client(socket_path) as c:
            before = ready_cycles(c)
            answer = c.request("submit", name="bench.nc", program=program_for(seconds))
            if not answer.get("ok"):  # the drives did not come back: the row says so, the next round tries again
                return before, before, f"not started ({answer.get('error')})"
            job = answer["job"]["id"]
            percent = 100
            while c.call("status").get("job") is not None:
                time.sleep(0.25)
                percent = 101 if percent == 100 else 100
                c.call("override", percent=percent)
            after = c.call("status")["cycles"]
            outcome = c.call("job", id=job)["job"]["outcome"]["outcome"]
        return before, after, outcome

    cpu_before = {name: cpu_s(pid) for name, pid in pids.items()}
    switches_before = normal_thread_switches(pids["daemon"])
    wall_before = time.monotonic()
    before, after, outcome = await asyncio.to_thread(run_job)
    wall = time.monotonic() - wall_before
    switches = switches_between(switches_before, normal_thread_switches(pids["daemon"]))
    cpu = {name: 100 * (cpu_s(pid) - cpu_before[name]) / wall for name, pid in pids.items()}
    stop.set()
    await asyncio.gather(*tasks, return_exceptions=True)
    for subscriber in direct:
        await asyncio.to_thread(subscriber.close)
    this_process_on(everywhere)
    label = f"{clients} {kind}" if clients else "0"
    if clients_cpus is not None:
        label += f", clients on CPU {','.join(map(str, sorted(clients_cpus)))}"
    total = sorted(t for t, _ in latencies)
    daemon_part = sorted(d for _, d in latencies)
    return {"clients": label, "outcome": outcome,
            "cycles": after["count"] - before["count"],
            "late": after["late"] - before["late"], "missed": after["missed"] - before["missed"],
            "events": len(latencies), "median_ms": median_ms(total), "p99_ms": p99_ms(total),
            "daemon_median_ms": median_ms(daemon_part), "daemon_p99_ms": p99_ms(daemon_part),
            "gateway_cpu_percent": cpu["gateway"], "daemon_cpu_percent": cpu["daemon"],
            "late_per_1000": 1000 * (after["late"] - before["late"]) / max(1, after["count"] - before["count"]),
            "normal_wakeups_per_s": switches / wall,
            # the cycle thread's background steps (fieldbus.cycle_slack; absent before it: -1)
            "slack_steps": after.get("slack_steps", -1) - before.get("slack_steps", 0),
            "slack_overruns": after.get("slack_overruns", -1) - before.get("slack_overruns", 0),
            "overrun_places": places_between(before.get("slack_overrun_places", {}),
                                             after.get("slack_overrun_places", {})),
            "load": Path("/proc/loadavg").read_text().split()[0]}


def places_between(before: dict[str, int], after: dict[str, int]) -> dict[str, int]:
    """The slack steps that overran a wake-up during a job, by where they ended
    (fieldbus.cycle_slack.step_place)."""
    return {place: n - before.get(place, 0) for place, n in after.items() if n > before.get(place, 0)}


def overrun_places_summary(rows: list[dict[str, Any]]) -> str:
    """Each kind of client's slack steps past a wake-up, summed over its jobs, by place."""
    lines = []
    for kind in dict.fromkeys(r["clients"] for r in rows):
        total: dict[str, int] = {}
        for r in rows:
            if r["clients"] == kind:
                for place, n in r.get("overrun_places", {}).items():
                    total[place] = total.get(place, 0) + n
        shown = ", ".join(f"{place} x{n}" for place, n in sorted(total.items(), key=lambda item: -item[1])) or "none"
        lines.append(f"- {kind}: {shown}")
    return "Slack steps past the wake-up, by where the step ended:\n\n" + "\n".join(lines)


def median_ms(sorted_s: list[float]) -> float:
    return statistics.median(sorted_s) * 1e3 if sorted_s else float("nan")


def p99_ms(sorted_s: list[float]) -> float:
    return sorted_s[int(0.99 * (len(sorted_s) - 1))] * 1e3 if sorted_s else float("nan")


async def idle_cpu(ws_url: str, gateway_pid: int, seconds: float) -> float:
    stop = asyncio.Event()
    task = asyncio.create_task(client(ws_url, [], stop))
    await asyncio.sleep(2.0)
    start_cpu, start = cpu_s(gateway_pid), time.monotonic()
    await asyncio.sleep(seconds)
    used = (cpu_s(gateway_pid) - start_cpu) / (time.monotonic() - start)
    stop.set()
    await asyncio.gather(task, return_exceptions=True)
    return 100 * used


def preview_ms(page_url: str, lines: int) -> float | None:
    chromium = shutil.which("chromium")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return None
    if chromium is None:
        return None
    folder = Path(tempfile.mkdtemp(prefix="nm-bench-web-"))
    program = folder / "surface.nc"
    rows = ["G21 G90 G00 Z5", "G01 Z0 F600"]
    for i in range(lines):  # a raster of short G01 moves, as 3-D surfacing posts write them
        row, col = divmod(i, 500)
        x = col * 0.2 if row % 2 == 0 else (499 - col) * 0.2
        rows.append(f"G01 X{x:.3f} Y{row * 0.2:.3f} Z{0.5 * ((x / 10) % 1):.3f} F3000")
    program.write_text("\n".join(rows) + "\n")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--headless", "--no-sandbox", "--disable-gpu",
                                                                    "--disable-background-networking"])
        page = browser.new_page(viewport={"width": 1600, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda err: errors.append(str(err)))
        page.goto(page_url)
        page.locator("#file").set_input_files(str(program))
        try:
            page.wait_for_function("() => window.previewDrawnMs !== undefined", timeout=60000)
        except Exception:
            raise RuntimeError(f"the preview was not drawn; page errors: {errors}") from None
        ms = float(page.evaluate("() => window.previewDrawnMs"))
        browser.close()
    return ms


class Running:
    """The daemon and the gateway started from ``src`` (a fresh folder, machine file and
    port), until ``stop``."""

    def __init__(self, src: Path, feedback_log: bool = True) -> None:
        self.src = src
        self.folder = Path(tempfile.mkdtemp(prefix="nm-bench-web-"))
        self.port = free_port()
        self.config = self.folder / "machine.yaml"
        self.socket_path = self.folder / "ctl.sock"
        self.config.write_text(MACHINE.format(channel=f"bench-web-{uuid.uuid4().hex}", socket=self.socket_path,
                                              data_dir=self.folder / "data", port=self.port)
                               + ("" if feedback_log else "monitoring: {feedback_log: false}\n"))
        self.base = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}/api/v1/ws"
        self.daemon: subprocess.Popen[bytes] | None = None
        self.gateway: subprocess.Popen[bytes] | None = None

    async def start(self) -> None:
        env = dict(os.environ, PYTHONPATH=str(self.src))
        self.daemon = subprocess.Popen([sys.executable, "-m", "nurbsmotion", "daemon", "--config", str(self.config)],
                                       env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(200):
            if self.socket_path.exists() or self.daemon.poll() is not None:
                break
            await asyncio.sleep(0.1)
        if not self.socket_path.exists():  # e.g. a previous checkout's src without its eds/ beside it
            raise RuntimeError(f"the daemon from {self.src} did not start (exit code {self.daemon.poll()}): "
                               f"try it with PYTHONPATH={self.src} python -m nurbsmotion daemon --config {self.config}")
        self.gateway = subprocess.Popen([sys.executable, "-m", "nurbsmotion", "web", "--config", str(self.config)],
                                        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        async with aiohttp.ClientSession() as session:
            for _ in range(200):
                try:
                    async with session.get(f"{self.base}/api/v1/status") as r:
                        if r.status == 200:
                            break
                except aiohttp.ClientError:
                    pass
                await asyncio.sleep(0.1)

    @property
    def pids(self) -> dict[str, int]:
        assert self.gateway is not None and self.daemon is not None
        return {"gateway": self.gateway.pid, "daemon": self.daemon.pid}

    def stop(self) -> None:
        for proc in (self.gateway, self.daemon):
            if proc is not None:
                stop_process(proc)


async def ab_rounds(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Rounds of 0 and ``args.clients`` WebSocket clients, each on this checkout's daemon and
    on the previous one's (``--previous-src``), alternating: both under the same load."""
    rows = []
    for _ in range(args.rounds):
        for label, src in (("before", args.previous_src), ("after", SRC)):
            running = Running(src)
            try:
                await running.start()
                for n in (0, args.clients):
                    row = await job_round(running.ws_url, str(running.socket_path), n, "WebSocket", args.seconds,
                                          running.pids)
                    rows.append({**row, "clients": f"{label}: {row['clients']}"})
                    print(rows[-1], flush=True)
            finally:
                running.stop()
    return rows


def late_summary(rows: list[dict[str, Any]]) -> str:
    """Late cycles per 1000 over all rounds of each kind of client, its rounds' event p99, and
    against the job without clients of the same round: the median of the paired differences
    with its sign-test interval (paired_median)."""
    out = ["| clients | rounds | late per 1000 cycles (all rounds) | paired difference to 0 clients per 1000: "
           "median [interval] | event -> client p99 ms |", "|---|---|---|---|---|"]
    none = [r for r in rows if r["clients"] == "0"]
    for kind in dict.fromkeys(r["clients"] for r in rows):
        group = [r for r in rows if r["clients"] == kind]
        late = per_1000(group)
        p99 = [r["p99_ms"] for r in group if r["events"]]
        shown = f"{min(p99):.1f}-{max(p99):.1f}" if p99 else "-"
        paired = "-"
        if kind != "0" and len(group) == len(none) > 1:
            median, low, high, confidence = paired_median([b["late_per_1000"] - a["late_per_1000"]
                                                           for a, b in zip(none, group)])
            paired = f"{median:+.1f} [{low:+.1f}, {high:+.1f}] ({confidence:.0%})"
        out.append(f"| {kind} | {len(group)} | {late:.1f} | {paired} | {shown} |")
    return "\n".join(out)


def ab_summary(rows: list[dict[str, Any]], clients: int) -> str:
    """Issue 22's late-cycle target for each side of an A/B run: late cycles per 1000 with 0
    and ``clients`` clients over all rounds, in how many rounds the clients' job had more
    late cycles than the job without clients of the same daemon, and the median of those
    paired differences with its distribution-free interval (paired_median)."""
    lines = ["| code | late per 1000, 0 clients | late per 1000, %d clients | rounds with more late cycles "
             "with clients | paired difference per 1000: median [interval] |" % clients, "|---|---|---|---|---|"]
    for label in ("before", "after"):
        none = [r for r in rows if r["clients"] == f"{label}: 0"]
        some = [r for r in rows if r["clients"] == f"{label}: {clients} WebSocket"]
        differences = [b["late_per_1000"] - a["late_per_1000"] for a, b in zip(none, some)]
        worse = sum(1 for d in differences if d > 0)
        median, low, high, confidence = paired_median(differences)
        lines.append(f"| {label} | {per_1000(none):.1f} | {per_1000(some):.1f} | {worse} of {len(some)} | "
                     f"{median:+.1f} [{low:+.1f}, {high:+.1f}] ({confidence:.0%}) |")
    return "\n".join(lines)


def paired_median(differences: list[float]) -> tuple[float, float, float, float]:
    """The median of the rounds' paired differences and the widest order-statistic interval
    [d_(j), d_(n+1-j)] that holds the true median with at least 90 % confidence by the sign
    test (distribution-free: one noisy round moves it by one rank, not by its size); the
    interval's confidence 1 - 2 P(Binomial(n, 1/2) < j). n < 5 gives the whole range."""
    d = sorted(differences)
    n = len(d)
    if n == 0:
        return math.nan, math.nan, math.nan, 0.0
    j = next((j for j in range(n // 2, 0, -1) if sign_test_confidence(n, j) >= 0.90), 1)
    return statistics.median(d), d[j - 1], d[n - j], sign_test_confidence(n, j)


def sign_test_confidence(n: int, j: int) -> float:
    """Confidence that [d_(j), d_(n+1-j)] of n sorted values holds their median: 1 - 2 P(B(n, 1/2) < j)."""
    return 1 - 2 * sum(math.comb(n, i) for i in range(j)) / 2 ** n


def slack_shown(count: int) -> str:
    """A slack counter's change over a job; '-' for a daemon without the counters."""
    return "-" if count < 0 else f"{count:,}"


def per_1000(rows: list[dict[str, Any]]) -> float:
    """Late cycles per 1000 cycles over ``rows`` (jobs)."""
    return 1000 * sum(r["late"] for r in rows) / max(1, sum(r["cycles"] for r in rows))


async def main_async(args: argparse.Namespace) -> tuple[str, str]:
    """The section's summary and its full result (every round's row)."""
    if args.previous_src is not None:
        rows = await ab_rounds(args)
        idle, preview = None, None
    else:
        running = Running(SRC, feedback_log=not args.no_feedback_log)
        try:
            await running.start()
            idle = await idle_cpu(running.ws_url, running.pids["gateway"], args.idle_seconds)
            rows = []
            kinds: list[tuple[int, str, set[int] | None]] = [(0, "WebSocket", None), (args.clients, "WebSocket", None),
                                                              (args.clients, "direct", None)]
            if args.clients_off_realtime_cpu:
                kinds.append((args.clients, "WebSocket", off_realtime_cpu()))
            for _ in range(args.rounds):
                for n, kind, cpus in kinds:
                    rows.append(await job_round(running.ws_url, str(running.socket_path), n, kind, args.seconds,
                                                running.pids, cpus))
                    print(rows[-1], flush=True)
            rows.append(await job_round(running.ws_url, str(running.socket_path), 1, "WebSocket",
                                        min(args.seconds, 20.0), running.pids))
            print(rows[-1], flush=True)
            preview = await asyncio.to_thread(preview_ms, running.base + "/", args.preview_lines)
        finally:
            running.stop()
    load = " / ".join(Path("/proc/loadavg").read_text().split()[:3])
    table = ["| clients | job outcome | cycles | late (> 10 % T) | late per 1000 cycles | missed (> T) | "
             "events timed | event -> client median ms | p99 ms | of which in the daemon: median ms | p99 ms | "
             "gateway CPU % | daemon CPU % | daemon normal-priority wake-ups/s | cycle-thread slack steps | "
             "of them past the wake-up | load (1 min) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        table.append(f"| {r['clients']} | {r['outcome']} | {r['cycles']:,} | {r['late']} | {r['late_per_1000']:.0f} | "
                     f"{r['missed']} | {r['events']} | {r['median_ms']:.1f} | {r['p99_ms']:.1f} | "
                     f"{r['daemon_median_ms']:.1f} | {r['daemon_p99_ms']:.1f} | "
                     f"{r['gateway_cpu_percent']:.1f} | {r['daemon_cpu_percent']:.0f} | "
                     f"{r['normal_wakeups_per_s']:.0f} | {slack_shown(r['slack_steps'])} | "
                     f"{slack_shown(r['slack_overruns'])} | {r['load']} |")
    if idle is None:
        return "", (f"This checkout's daemon and gateway against the previous one's (`--previous-src`), restarted "
                f"for each: {args.seconds:g} s jobs with 0 and {args.clients} WebSocket clients, before and after "
                f"alternating round by round. Load average at the end: {load}.\n\n" + "\n".join(table) + "\n\n"
                + ab_summary(rows, args.clients) + "\n")
    shown = "not measured (no chromium or playwright)" if preview is None else f"{preview:.0f} ms"
    figures = (f"| figure | value | target |\n|---|---|---|\n"
               f"| gateway CPU, idle, one client connected ({args.idle_seconds:g} s) | {idle:.2f} % | < 1 % |\n"
               f"| preview of a {args.preview_lines:,}-line program parsed and drawn (headless Chromium) | {shown} "
               f"| <= 2000 ms |\n")
    summary = (f"{args.seconds:g} s jobs at T = 1 ms, the clients interleaved round by round; load average at the "
               f"end: {load}.\n\n{late_summary(rows)}\n\n{figures}")
    return summary, (f"The daemon (three simulated drives, T = 1 ms) and `nurbsmotion web` as separate processes, "
            f"clients in the benchmark's process; {args.seconds:g} s jobs with 0 clients, {args.clients} WebSocket "
            f"clients (one daemon subscription in the gateway) and {args.clients} direct subscribers on the control "
            f"socket, interleaved round by round, then one with 1 WebSocket client; the override set every 0.25 s "
            f"gives the clients events to time. "
            f"Load average at the end: {load} (2 cores shared with other work: compare rows of one run).\n\n"
            + "\n".join(table) + "\n\n" + overrun_places_summary(rows) + "\n\n" + figures)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--clients", type=int, default=10)
    parser.add_argument("--idle-seconds", type=float, default=30.0)
    parser.add_argument("--preview-lines", type=int, default=100_000)
    parser.add_argument("--no-write", action="store_true")
    parser.add_argument("--previous-src", type=Path,
                        help="src/ of a previous checkout (with its eds/ beside it): its daemon against this one's, "
                             "round by round (printed only)")
    parser.add_argument("--no-feedback-log", action="store_true",
                        help="the daemon without the jobs' feedback.csv (monitoring.feedback_log: false; before "
                             "2026-11-29 the benchmark always ran so)")
    parser.add_argument("--clients-off-realtime-cpu", action="store_true",
                        help="also, each round, the WebSocket clients with this process kept off the daemon's "
                             "real-time CPU (as browsers elsewhere, or isolcpus, keep them)")
    args = parser.parse_args()
    summary, body = asyncio.run(main_async(args))
    command = f"python benchmarks/bench_web.py --seconds {args.seconds:g} --rounds {args.rounds}" + (
        " --clients-off-realtime-cpu" if args.clients_off_realtime_cpu else "")
    if args.no_write or args.previous_src is not None:
        print(body)
    else:
        write_section("web", "Web gateway: event latency, cycles with clients, CPU, preview", summary, command,
                      detail=body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
