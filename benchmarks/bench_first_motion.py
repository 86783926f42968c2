"""Streamed jobs in the daemon: time to first motion and the daemon's peak memory on long
programs at T = 1 ms (issue 17: first motion within 1.0 s of the submission, peak RSS under
200 MB for the 13-minute program and a one-hour one).

Each program runs in a fresh process holding the daemon (service.daemon.Daemon: control
socket, controller, master, the job planner) and three simulated drives on python-can's
virtual bus, as ``simulate: true`` does, except that the drives record nothing (a recording
keeps ~120 bytes per drive and set-point by design, fieldbus-independent: 280 MB for 13
minutes). The program goes through the control socket like ``nurbsmotion run``;
feedback.csv and the trace are written into the job record as usual.

- time to first motion: from the submit request to the first cycle whose set-point leaves
  the held position (the master's cycle counter and the job's start cycle, fieldbus.Master);
  the submission waits until the daemon's planner worker has started (its imports: a
  submission in the first second after the daemon's start waits for them as well);
- peak RSS: the process' VmHWM at the job's end (everything: interpreter, numpy, drives);
  the planner worker (service.planner_worker, a separate process) reported apart: its
  VmHWM sampled once a second while the job runs.

Programs: Wang's Table 1 curve repeated (bench_plan_command.wang_copies), J = 50000 mm/s^3,
chord error 1 um as Wang's: 8 copies ~ 1 min, 100 copies ~ 13 min, 460 copies ~ 1 h; each
runs for its whole motion time.

The simulated drives' receive and ticker threads run SCHED_FIFO just below the master's, as
the daemon runs them with ``simulate: true`` (service.link.open_link): each stands in for a
drive's own CPU (docs/daemon.md, "Simulated drives in the daemon's process").

``--program FILE --copies N``: a real program instead of Wang's curve, N times in a row (its
end M2/M30 and % lines dropped between copies; tools 1-99 as the CAM corpus test reads them):
what a real CAM program waits before moving. With ``--first-motion-only`` for long ones.

``--first-motion-only``: each job is stopped (the controlled stop) at its first motion and the
row says so (memory and missed cycles then cover those seconds only): first motion of the
one-hour program without its hour.

Run: python benchmarks/bench_first_motion.py [--copies 8 100 460] [--results FILE] [--first-motion-only]
(``--results``: every result is also appended to FILE, and the table is written from all the
results in FILE, so programs run by separate invocations, e.g. at the same time, share it;
``--copies --results FILE`` runs nothing and writes the table again.)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_plan_command import wang_copies  # noqa: E402

TOOLS_YAML = "tools:\n" + "".join(f"  - {{number: {n}, length_mm: {40 + n}, diameter_mm: 6}}\n" for n in range(1, 100))
def master_job(master: Any) -> Any:
    """The master's job playing now (None: none), whichever attribute holds it."""
    loop = getattr(master, "_loop", None)
    return loop.job if loop is not None else getattr(master, "_job", None)


TARGET_FIRST_S = 1.0
TARGET_MB = 200.0
CONFIG = """\
cycle_period_ms: 1
simulate: true
bus: {{interface: virtual, channel: {channel}}}
interpolation: {{algorithm: lookahead, feed_mm_min: 12000, rapid_feed_mm_min: 12000, chord_error_mm: 0.001,
                max_accel_mm_s2: 2500, max_jerk_mm_s3: 50000, acc_time_s: 1.2}}
axes:
  - {{name: X, node_id: 1, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-200, 200],
     max_velocity_mm_s: 400, max_accel_mm_s2: 5000, following_error_window_mm: 2.0}}
  - {{name: Y, node_id: 2, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-200, 200],
     max_velocity_mm_s: 400, max_accel_mm_s2: 5000, following_error_window_mm: 2.0}}
  - {{name: Z, node_id: 3, mode: csp, counts_per_mm: 1000, soft_limits_mm: [-200, 200],
     max_velocity_mm_s: 400, max_accel_mm_s2: 5000, following_error_window_mm: 2.0}}
monitoring: {{traffic_log: none}}
control: {{socket: {socket}}}
data_dir: {data_dir}
{extra}"""
# A real program's machine: tools 1-99 and a spindle drive (simulated too) for its M3/S words.
PROGRAM_MACHINE = """\
tools: tools.yaml
spindle: {node_id: 5, counts_per_rev: 4096, max_rpm: 24000, accel_rpm_s: 8000}
"""


def status_kb(field: str, pid: int | str = "self") -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1])
    return float("nan")


def program_copies(path: Path, copies: int) -> str:
    """``path``'s G-code ``copies`` times in a row, ending once (its M2/M30 and % lines dropped).
    Each copy starts where the last ended: a CAM program's first move is a positioning one."""
    ends = ("M2", "M02", "M30", "%")
    body = [line for line in path.read_text().splitlines()
            if line.strip().upper().split(";")[0].strip() not in ends]
    return "\n".join(body * copies + ["M30"]) + "\n"


def program_label(r: dict) -> str:
    return f"{r['program']} x {r['copies']}" if r.get("program") else f"Wang x {r['copies']}"


def one_run(copies: int, first_motion_only: bool = False, program: Path | None = None) -> dict:
    """The daemon in this process runs Wang x ``copies`` (or ``program`` x ``copies``) once (see
    the module docstring)."""
    from nurbsmotion.config import parse_config
    from nurbsmotion.fieldbus import Master
    from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY, SIM_DRIVES_PRIORITY
    from nurbsmotion.service.client import Client
    from nurbsmotion.service.daemon import Daemon
    from nurbsmotion.service.link import SimulatedDrives
    from nurbsmotion.sim import SimNetwork

    work = Path(tempfile.mkdtemp(prefix="fm-"))
    (work / "tools.yaml").write_text(TOOLS_YAML)
    config = parse_config(CONFIG.format(channel=f"fm-{uuid.uuid4().hex}", socket=work / "ctl.sock",
                                        data_dir=work / "var", extra=PROGRAM_MACHINE if program else ""),
                          str(work / "machine.yaml"), base_dir=work)
    masters: list[Master] = []
    networks = []

    def open_motion(cfg):
        drives = SimulatedDrives(cfg, rt_priority=SIM_DRIVES_PRIORITY)  # as service.link.open_link
        drives.network = SimNetwork.for_machine(cfg, record=False)  # see the module docstring
        drives.start()
        networks.append(drives.network)
        master = Master(cfg, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze")
        master.bring_up()
        masters.append(master)
        return master, drives

    text = wang_copies(copies) if program is None else program_copies(program, copies)
    name = f"wang_x{copies}.nc" if program is None else f"{program.stem}_x{copies}{program.suffix}"
    daemon = Daemon(config, open_motion)
    daemon.start()
    worker = getattr(daemon, "planner_worker", None)  # None: a daemon that plans in its own process
    if worker is not None:
        worker.wait_ready()  # a user's submission comes later than this one: the worker has imported the planner
    rss_idle_mb = status_kb("VmRSS") / 1024.0
    try:
        with Client(config.control.socket) as client:
            started = time.perf_counter()
            answer = client.call("submit", name=name, program=text)
            submit_s = time.perf_counter() - started
            job_id = answer["job"]["id"]
            master = masters[0]
            job = master_job(master)
            while job is None or job.index < 1:  # the first row is the held position: row 1 moves
                time.sleep(0.0005)
                job = master_job(master)
            first_motion_s = time.perf_counter() - started
            if first_motion_only:
                client.call("stop")
            samples = []
            worker_pid = worker.pid if worker is not None else None
            worker_peak_mb = float("nan")
            while True:
                status = client.call("status")
                samples.append(status_kb("VmRSS") / 1024.0)
                if worker_pid is not None:
                    worker_peak_mb = status_kb("VmHWM", worker_pid) / 1024.0
                if status["job"] is None:
                    break
                time.sleep(1.0)
            info = client.call("job", id=job_id)["job"]
    finally:
        daemon.close()
    outcome, plan = info["outcome"], info["plan"]
    return {"copies": copies, "program": program.name if program else None, "lines": text.count("\n"),
            "cycles": plan["cycles"], "duration_s": plan["duration_s"],
            "planned_all": bool(plan.get("planned_all")),
            "outcome": outcome["outcome"], "reason": outcome["reason"], "sent": outcome["sent"],
            "submit_s": submit_s, "first_motion_s": first_motion_s, "first_chunk_s": plan.get("first_chunk_s"),
            "planning_time_s": plan.get("planning_time_s"), "missed": outcome["missed_cycles"],
            "late": outcome["late_cycles"], "rss_idle_mb": rss_idle_mb,
            "rss_max_sampled_mb": max(samples), "peak_rss_mb": status_kb("VmHWM") / 1024.0,
            "worker_peak_rss_mb": worker_peak_mb,
            "wall_s": outcome["motion_time_s"], "sim_threads": dict(networks[0].thread_policy),
            "first_motion_only": first_motion_only}


def run_child(copies: int, first_motion_only: bool, program: Path | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    load_before = load_line()
    out = subprocess.run([sys.executable, __file__, "--child", str(copies)] + ["--first-motion-only"] * first_motion_only
                         + (["--program", str(program)] if program else []),
                         capture_output=True, text=True, env=env, timeout=2 * 3600)
    run = {"started": started, "load_before": load_before, "load_after": load_line()}
    if out.returncode != 0:
        return {"copies": copies, "program": program.name if program else None, **run,
                "error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed"}
    return {**json.loads(out.stdout.strip().splitlines()[-1]), **run}


def load_line() -> str:
    one, five, fifteen = os.getloadavg()
    return f"{one:.1f} / {five:.1f} / {fifteen:.1f}"


def table(results: list[dict]) -> str:
    rows = ["| program | started | host load (1/5/15 min) before → after | cycles (motion time) | outcome | submit answered s | first motion s | first chunk planned s "
            "| planning s | missed / late cycles | daemon RSS idle MB | daemon peak RSS MB | planner worker peak RSS MB "
            "| drives' receive / ticker thread | targets (first motion < 1.0 s, daemon peak < 200 MB) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        run = f"| {program_label(r)} | {r.get('started', '')} | {r.get('load_before', '')} → {r.get('load_after', '')} "
        if "error" in r:
            rows.append(f"{run}| failed: {r['error']} | | | | | | | | | | | |")
            continue
        met = r["first_motion_s"] < TARGET_FIRST_S and r["peak_rss_mb"] < TARGET_MB
        so_far = "" if r.get("planned_all") else ", planned when it ended"
        if r.get("first_motion_only"):
            so_far += ", stopped at first motion (--first-motion-only)"
        threads = r.get("sim_threads", {})
        rows.append(f"{run}| {r['cycles']:,} ({r['duration_s'] / 60:.1f} min{so_far}) | {r['outcome']}"
                    f"{': ' + r['reason'] if r['reason'] else ''} | {r['submit_s']:.3f} | {r['first_motion_s']:.3f} | "
                    f"{r['first_chunk_s']:.3f} | {r['planning_time_s']:.1f} | {r['missed']} / {r['late']} | "
                    f"{r['rss_idle_mb']:.0f} | {r['peak_rss_mb']:.0f} | {r['worker_peak_rss_mb']:.0f} | "
                    f"{threads.get('receive', '?')} / {threads.get('ticker', '?')} | "
                    f"{'met' if met else 'NOT met'} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, nargs="*", default=[8, 100, 460])
    parser.add_argument("--results", type=Path, help="JSON lines: append each result, write the table from all")
    parser.add_argument("--first-motion-only", action="store_true", help="stop each job at its first motion")
    parser.add_argument("--program", type=Path, help="a G-code file instead of Wang's curve (--copies: how many times)")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(one_run(args.child, args.first_motion_only, args.program)))
        return
    results = []
    for copies in args.copies:
        results.append(run_child(copies, args.first_motion_only, args.program))
        print(json.dumps(results[-1]), flush=True)
        if args.results is not None:
            with args.results.open("a") as out:
                out.write(json.dumps(results[-1]) + "\n")
    if args.results is not None:
        results = sorted((json.loads(line) for line in args.results.read_text().splitlines() if line.strip()),
                         key=lambda r: (r.get("program") or "", r["copies"], r.get("started", "")))
    body = ("The daemon (control socket, controller, master) and three simulated drives recording "
            "nothing, in one process on python-can's virtual bus (the drives' receive and ticker threads SCHED_FIFO "
            "below the master's, as the daemon runs them), the job planned in the daemon's planner worker "
            "process, T = 1 ms, lookahead with J = 50000 mm/s^3 and "
            "1 um chord error; each program submitted through the control socket and run to its end. First motion: "
            "submit request to the first set-point that leaves the held position. Peak RSS: the process' VmHWM. "
            "Host load: the load average before and after each run (2 cores shared with other sessions)."
            "\n\n" + table(results))
    command = "python benchmarks/bench_first_motion.py --copies " + " ".join(str(c) for c in args.copies)
    if args.results is not None:  # the rows may come from several invocations sharing the file
        command = "python benchmarks/bench_first_motion.py --copies N... --results FILE"
        body += ("\n\nRows from one or more invocations sharing FILE (each appends its results; "
                 "`--copies --results FILE` writes this table again from FILE).")
    write_section("first_motion", "Streamed jobs: time to first motion and daemon memory", body, command)


if __name__ == "__main__":
    main()
