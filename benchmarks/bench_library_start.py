"""Time to the first set-point from ``start NAME`` (a library program) and from ``run FILE``
(the first and the second time) for a real CAM program (issue 25 item 1).

One fresh process per size holds the daemon and its simulated drives exactly as
bench_first_motion does (its machine: T = 1 ms, lookahead J = 50000, a spindle and tools
1-99 for the program's words). Through the control socket, from the same held position
(the machine's 0, 0, 0: the checked-program store's key includes where a program starts):

1. ``submit`` (what ``run FILE`` sends) of the program never seen: read and checked, stored;
2. ``submit`` of it again: loaded from the store;
3. ``programs.add`` of it under another name (the add's check, timed: it runs while the
   machine is idle, before any start), then ``start NAME``: loaded from the store.

Each job is stopped (controlled stop) at its first motion, the axes sent back to 0 by MDI
``G53 G0 X0 Y0 Z0``; each row says whether the store served it (the job's
``checked_from_store``). First set-point: from the request to the first cycle whose
set-point leaves the held position (the master's job index >= 1); it includes the program's
spindle spin-up (S5000 M3 at 8000 rpm/s: 0.625 s), and the job's ``first_chunk_s`` (request
to the first planned chunk in the daemon) is shown beside it. Each request is sent by a
client process of its own, the program as ``run`` and ``programs add`` send it: the open file
passed along (protocol ``program_fd``; ``--text``: its text, as a remote client sends it), so
that the daemon's process holds only what the daemon holds.

Peak memory of each step: the daemon's process (with its simulated drives, its allocator set as
``nurbsmotion daemon`` sets it: runtime.keep_freed_memory) and the planner worker's VmHWM (/proc/PID/status), both reset before the step (``5`` into
/proc/PID/clear_refs) and read at the first set-point (the add's: at its answer, with the
checker process' peak as well).

``--cpu``: instead, where the time before the first set-point goes, in CPU seconds of one
process (time.process_time: far less sensitive to a loaded host than wall time): reading and
checking (what the store saves), loading the store's entry, pickling the checked program for
the daemon (the worker's share of the transfer), and the planner's first chunk.

Run: python benchmarks/bench_library_start.py [--copies 2 19] [--program FILE] [--text] [--cpu]
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
from benchmarks.bench_first_motion import (CONFIG, PROGRAM_MACHINE, TOOLS_YAML, load_line, master_job,  # noqa: E402
                                           program_copies, status_kb)

PROGRAM = ROOT / "tests" / "data" / "gcode" / "fusion360_led_floor_1121_btn8copies_20bit.nc"
TARGET_START_S = 1.0
TARGET_DAEMON_MB = 150.0  # issue 25 item 7, a 10^6-line program
TARGET_WORKER_MB = 300.0


CLIENT = """
import json, sys, time
from nurbsmotion.service.client import Client, RequestFailed
socket, cmd, fields, program_file, as_text = sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), sys.argv[4], sys.argv[5]
files = []
if program_file and as_text:
    fields["program"] = open(program_file, encoding="utf-8").read()
elif program_file:  # as run and programs add send it: the open file (protocol program_fd)
    src = open(program_file, "rb")
    files, fields["program_fd"] = [src.fileno()], 0
with Client(socket, timeout_s=900.0) as client:
    started = time.perf_counter()  # CLOCK_MONOTONIC: the daemon's process reads the same clock
    try:
        answer = client.call(cmd, files=files, **fields)
    except RequestFailed as err:
        answer = {"ok": False, "error": str(err)}
print(json.dumps({"started": started, "answer": answer}))
"""
SEND_TEXT = False  # --text: each program sent as its text (a remote client's way), not as the open file


def write_copies(program: Path, copies: int, path: Path) -> int:
    """``program`` x ``copies`` into ``path`` (its lines), built in a process of its own: the
    text's temporaries (a few times 17.5 MB at 10^6 lines) would otherwise stay in this
    process' heap and count as the daemon's memory."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    code = ("import sys; from pathlib import Path; sys.path.insert(0, sys.argv[1]); "
            "from benchmarks.bench_first_motion import program_copies; "
            "text = program_copies(Path(sys.argv[2]), int(sys.argv[3])); Path(sys.argv[4]).write_text(text); "
            "print(text.count(chr(10)))")
    out = subprocess.run([sys.executable, "-c", code, str(ROOT), str(program), str(copies), str(path)],
                         capture_output=True, text=True, env=env, check=True)
    return int(out.stdout.strip())


def reset_peak(*pids: int | None) -> None:
    """VmHWM back to the current RSS (Linux: '5' into /proc/PID/clear_refs)."""
    for pid in pids:
        if pid is not None:
            Path(f"/proc/{pid}/clear_refs").write_text("5")


def peak_mb(pid: int | str | None) -> float:
    return status_kb("VmHWM", pid) / 1024.0 if pid is not None else float("nan")


def request(socket: Path, cmd: str, fields: dict[str, Any], program_file: Path | None) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    return subprocess.Popen([sys.executable, "-c", CLIENT, str(socket), cmd, json.dumps(fields), str(program_file or ""),
                             "1" if SEND_TEXT else ""], stdout=subprocess.PIPE, text=True, env=env)


def answer_of(client: subprocess.Popen[str]) -> tuple[float, dict[str, Any]]:
    out, _ = client.communicate(timeout=900)
    reply = json.loads(out.strip().splitlines()[-1])
    return float(reply["started"]), reply["answer"]


def first_setpoint(client: Any, socket: Path, master: Any, worker_pid: int | None, cmd: str,
                   program_file: Path | None = None, **fields: Any) -> dict[str, Any]:
    """Send ``cmd`` from a client process; seconds until the master's job sends its second row
    (the first that moves) and the peaks meanwhile, then a controlled stop and the axes back
    at 0 (MDI)."""
    recover(client)
    reset_peak(os.getpid(), worker_pid)
    sender = request(socket, cmd, fields, program_file)
    job = master_job(master)
    while (job is None or job.index < 1) and sender.poll() is None:
        time.sleep(0.0005)
        job = master_job(master)
    moved = time.perf_counter()
    daemon_mb, worker_mb = peak_mb("self"), peak_mb(worker_pid)
    rss_mb = [status_kb(f, "self") / 1024.0 for f in ("RssAnon", "RssFile")]  # what the daemon's RSS is now
    started, answer = answer_of(sender)
    if not answer.get("ok"):
        raise RuntimeError(f"{cmd}: {answer.get('error')}")
    while job is None or job.index < 1:  # the answer came first
        time.sleep(0.0005)
        job = master_job(master)
        moved = time.perf_counter()
    client.call("stop")
    idle(client)
    recover(client)
    client.call("mdi", text="G53 G0 X0 Y0 Z0")
    idle(client)
    return {"s": moved - started, "first_chunk_s": answer["job"]["summary"].get("first_chunk_s", float("nan")),
            "from_store": answer["job"]["summary"]["checked_from_store"],
            "blocks": answer["job"]["summary"]["blocks"], "daemon_mb": daemon_mb, "worker_mb": worker_mb,
            "daemon_anon_file_mb": rss_mb}


def recover(client: Any) -> None:
    """Drives in fault (a loaded host's lost heartbeat, not what is measured): reset them."""
    for _ in range(40):
        if client.call("status")["state"] != "fault":
            return
        client.request("reset")  # refused while the drives come back: asked again
        time.sleep(0.5)


def checker_pid(daemon: Any) -> int | None:
    pool = daemon.programs.checker._pool if daemon.programs is not None else None
    processes = list(getattr(pool, "_processes", {}) or {})
    return processes[0] if processes else None


def idle(client: Any, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while client.call("status")["job"] is not None:
        if time.monotonic() > deadline:
            raise TimeoutError("the job did not end")
        time.sleep(0.05)


def one_size(program: Path, copies: int) -> dict[str, Any]:
    """The three starts of ``program`` x ``copies`` in one daemon (module docstring)."""
    from nurbsmotion.config import parse_config
    from nurbsmotion.fieldbus import Master
    from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY, SIM_DRIVES_PRIORITY, keep_freed_memory
    from nurbsmotion.service.client import Client
    from nurbsmotion.service.daemon import Daemon
    from nurbsmotion.service.link import SimulatedDrives
    from nurbsmotion.sim import SimNetwork

    keep_freed_memory()  # as `nurbsmotion daemon` sets its process (runtime.py): freed heap kept
    work = Path(tempfile.mkdtemp(prefix="lib-"))
    (work / "tools.yaml").write_text(TOOLS_YAML)
    config = parse_config(CONFIG.format(channel=f"lib-{uuid.uuid4().hex}", socket=work / "ctl.sock",
                                        data_dir=work / "var", extra=PROGRAM_MACHINE),
                          str(work / "machine.yaml"), base_dir=work)
    masters: list[Master] = []

    def open_motion(cfg: Any) -> Any:
        drives = SimulatedDrives(cfg, rt_priority=SIM_DRIVES_PRIORITY)
        drives.network = SimNetwork.for_machine(cfg, record=False)
        drives.start()
        master = Master(cfg, rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze")
        master.bring_up()
        masters.append(master)
        return master, drives

    name = f"{program.stem}_x{copies}{program.suffix}"
    program_file = work / name
    lines = write_copies(program, copies, program_file)  # the daemon's process holds only what the daemon holds
    daemon = Daemon(config, open_motion)
    daemon.start()
    assert daemon.planner_worker is not None
    daemon.planner_worker.wait_ready()
    worker = daemon.planner_worker.pid
    socket = config.control.socket
    try:
        with Client(socket, timeout_s=900.0) as client:
            first = first_setpoint(client, socket, masters[0], worker, "submit", program_file, name=name)
            second = first_setpoint(client, socket, masters[0], worker, "submit", program_file, name=name)
            library_name = f"lib_{name}"
            reset_peak(os.getpid())
            adding = request(socket, "programs.add", {"name": library_name}, program_file)
            added_at, added = answer_of(adding)
            add_s = time.perf_counter() - added_at
            add_mb = (peak_mb("self"), peak_mb(checker_pid(daemon)))
            if not added.get("ok"):
                raise RuntimeError(f"programs.add: {added.get('error')}")
            start = first_setpoint(client, socket, masters[0], worker, "start", name=library_name)
            counters = client.call("programs.list")["checked_store"]
    finally:
        daemon.close()
    return {"program": program.name, "copies": copies, "lines": lines, "blocks": first["blocks"],
            "run_first_s": first["s"], "run_first_from_store": first["from_store"],
            "run_second_s": second["s"], "run_second_from_store": second["from_store"],
            "add_s": add_s, "start_s": start["s"], "start_from_store": start["from_store"],
            "first_chunk_s": {"run_first": first["first_chunk_s"], "run_second": second["first_chunk_s"],
                              "start": start["first_chunk_s"]},
            "daemon_anon_file_mb": {"run_first": first["daemon_anon_file_mb"], "run_second": second["daemon_anon_file_mb"],
                                    "start": start["daemon_anon_file_mb"]},
            "store_hits": counters["hits"], "store_misses": counters["misses"],
            "peak_mb": {"run_first": [first["daemon_mb"], first["worker_mb"]],
                        "run_second": [second["daemon_mb"], second["worker_mb"]],
                        "add": list(add_mb), "start": [start["daemon_mb"], start["worker_mb"]]}}


def cpu_steps(program: Path, copies: int) -> dict[str, Any]:
    """CPU seconds of each step before the first set-point, in this process (``--cpu``)."""
    import pickle

    import numpy as np

    from nurbsmotion.config import parse_config
    from nurbsmotion.planning.limits import limits_from_config
    from nurbsmotion.planning.lookahead import PlanStream
    from nurbsmotion.service.checked_store import load_checked, save_checked
    from nurbsmotion.service.planner_worker import read_and_check, send_program
    from nurbsmotion.service.streamed_job import CHUNK_CYCLES, FIRST_CHUNK_CYCLES, plan_request

    work = Path(tempfile.mkdtemp(prefix="lib-cpu-"))
    (work / "tools.yaml").write_text(TOOLS_YAML)
    config = parse_config(CONFIG.format(channel="cpu", socket=work / "ctl.sock", data_dir=work / "var",
                                        extra=PROGRAM_MACHINE), str(work / "machine.yaml"), base_dir=work)
    text = program_copies(program, copies)
    request = plan_request(program.name, text, config, np.zeros(3))

    def cpu(step: Any) -> tuple[float, Any]:
        t0 = time.process_time()
        value = step()
        return time.process_time() - t0, value

    read_s, checked = cpu(lambda: read_and_check(request))
    entry = work / "entry.checked"
    save_s, _ = cpu(lambda: save_checked(entry, "key", checked))
    load_s, loaded = cpu(lambda: load_checked(entry, "key"))

    class Sink:
        size = 0

        def send(self, message: Any) -> None:
            Sink.size += len(pickle.dumps(message))

    transfer_s, _ = cpu(lambda: send_program(Sink(), loaded, True, entry))
    stream = PlanStream(loaded, limits_from_config(config), CHUNK_CYCLES, FIRST_CHUNK_CYCLES)
    first_chunk_s, _ = cpu(lambda: next(iter(stream.chunks())))
    return {"program": program.name, "copies": copies, "lines": text.count("\n"), "blocks": len(checked.blocks),
            "read_check_cpu_s": read_s, "store_save_cpu_s": save_s, "store_load_cpu_s": load_s,
            "transfer_pickle_cpu_s": transfer_s, "transfer_mb": Sink.size / 1e6, "entry_mb": entry.stat().st_size / 1e6,
            "first_chunk_cpu_s": first_chunk_s}


def cpu_table(results: list[dict[str, Any]]) -> str:
    rows = ["| program | lines (blocks) | read + check (saved by the store) | write the entry (entry MB) "
            "| map the entry (worker, daemon: each) | to the daemon: pickle s (MB) | planner's first chunk "
            "| started, load before → after |",
            "|---|---|---|---|---|---|---|---|"]
    for r in results:
        head = f"| {r['program']} x {r['copies']} "
        if "error" in r:
            rows.append(f"{head}| failed: {r['error']} | | | | | | {r['started']}, {r['load_before']} |")
            continue
        rows.append(f"{head}| {r['lines']:,} ({r['blocks']:,}) | {r['read_check_cpu_s']:.2f} | "
                    f"{r['store_save_cpu_s']:.2f} ({r['entry_mb']:.1f}) | {r['store_load_cpu_s']:.3f} "
                    f"| {r['transfer_pickle_cpu_s']:.3f} ({r['transfer_mb']:.3f}) | {r['first_chunk_cpu_s']:.2f} "
                    f"| {r['started']}, {r['load_before']} → {r['load_after']} |")
    return "\n".join(rows)


def run_child(program: Path, copies: int, cpu: bool = False, as_text: bool = False) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    before = load_line()
    out = subprocess.run([sys.executable, __file__, "--child", str(copies), "--program", str(program)]
                         + ["--cpu"] * cpu + ["--text"] * as_text, capture_output=True, text=True, env=env,
                         timeout=3600)
    run = {"started": started, "load_before": before, "load_after": load_line()}
    if out.returncode != 0:
        tail = out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed"
        return {"program": program.name, "copies": copies, "error": tail, **run}
    return {**json.loads(out.stdout.strip().splitlines()[-1]), **run}


def served(seconds: float, from_store: bool, first_chunk_s: float | None = None) -> str:
    chunk = f"; first chunk {first_chunk_s:.2f}" if first_chunk_s is not None else ""
    return f"{seconds:.2f} ({'store' if from_store else 'read + checked'}{chunk})"


def peaks(r: dict[str, Any], step: str) -> str:
    daemon, other = r["peak_mb"][step]
    return f"{daemon:.0f} / {other:.0f}"


def table(results: list[dict[str, Any]]) -> str:
    rows = ["| program | lines (blocks) | `run FILE` 1st: s to first set-point | `run FILE` 2nd | `programs add` (check) s "
            "| `start NAME` | peak MB daemon / worker: 1st `run`, 2nd `run`, `start` (daemon / checker: `add`) "
            "| store hits / misses | target start <= 1.0 s, daemon < 150 MB, worker < 300 MB "
            "| started, load before → after |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        head = f"| {r['program']} x {r['copies']} "
        if "error" in r:
            rows.append(f"{head}| failed: {r['error']} | | | | | | | | {r['started']}, {r['load_before']} |")
            continue
        daemon_peak = max(r["peak_mb"][step][0] for step in ("run_first", "run_second", "start", "add"))
        worker_peak = max(r["peak_mb"][step][1] for step in ("run_first", "run_second", "start"))
        met = [r["start_s"] <= TARGET_START_S, daemon_peak < TARGET_DAEMON_MB, worker_peak < TARGET_WORKER_MB]
        rows.append(f"{head}| {r['lines']:,} ({r['blocks']:,}) | {served(r['run_first_s'], r['run_first_from_store'])} "
                    f"| {served(r['run_second_s'], r['run_second_from_store'])} | {r['add_s']:.2f} "
                    f"| {served(r['start_s'], r['start_from_store'], r['first_chunk_s']['start'])} "
                    f"| {peaks(r, 'run_first')}, {peaks(r, 'run_second')}, {peaks(r, 'start')} ({peaks(r, 'add')}) "
                    f"| {r['store_hits']} / {r['store_misses']} "
                    f"| {', '.join('met' if m else 'NOT met' for m in met)} "
                    f"| {r['started']}, {r['load_before']} → {r['load_after']} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, nargs="*", default=[2, 19])
    parser.add_argument("--program", type=Path, default=PROGRAM)
    parser.add_argument("--cpu", action="store_true", help="CPU seconds of each step instead (module docstring)")
    parser.add_argument("--text", action="store_true", help="send each program as its text, not the open file")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        global SEND_TEXT
        SEND_TEXT = args.text
        print(json.dumps(cpu_steps(args.program, args.child) if args.cpu else one_size(args.program, args.child)))
        return
    results = []
    for copies in args.copies:
        results.append(run_child(args.program, copies, args.cpu, args.text))
        print(json.dumps(results[-1]), flush=True)
    if args.cpu:
        body = ("CPU seconds (time.process_time) of each step before a streamed job's first set-point, one process, "
                "bench_first_motion's machine (T = 1 ms, J = 50000, 1 um chord error): what `start NAME` and a "
                "second `run FILE` skip (read + check) and what they still pay: mapping the store's entry (the worker, then "
                "the daemon: service.checked_store), the one message to the daemon (the program's outline and the "
                "entry's path) and the planner's first chunk (its first sections, setup.PathSections). A program "
                "read now also pays the entry's write.\n\n" + cpu_table(results))
        write_section("library_start_cpu", "Library starts: where the time to the first set-point goes (CPU)", body,
                      "python benchmarks/bench_library_start.py --cpu --copies "
                      + " ".join(str(c) for c in args.copies))
        return
    body = ("The daemon and three simulated drives in one process (bench_first_motion's machine: T = 1 ms, "
            "lookahead J = 50000 mm/s^3, 1 um chord error, spindle, tools 1-99); each request through the control "
            "socket from the held position 0, 0, 0; each job stopped at its first motion and the axes sent back "
            "by MDI. Seconds from the request to the first set-point that moves (the program's spindle spin-up, "
            "0.625 s, included; `start NAME`: the job's first chunk planned after, in the daemon); in brackets whether the "
            "planner worker read and checked the program or loaded it checked from DATA_DIR/checked "
            "(service.checked_store). `programs add`: the request's answer, the check done in the checker "
            "process. Host: 2 cores shared with other sessions (load average before → after).\n\n" + table(results))
    command = "python benchmarks/bench_library_start.py --copies " + " ".join(str(c) for c in args.copies) \
        + " --text" * args.text
    write_section("library_start", "Library starts: `start NAME` and `run FILE` to the first set-point", body,
                  command)


if __name__ == "__main__":
    main()
