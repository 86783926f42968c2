"""Start-up time of the `nurbsmotion` command (issue 25, part 5): how long a control command
takes before it does anything, this checkout against a previous one.

Each case is the real command in a fresh interpreter (`python -m nurbsmotion ...`), RUNS times;
the table gives the median wall time and the median CPU time of the child (os.wait4: user +
system), which a loaded machine inflates less. Target: `--help`, `status`, `hold` and `jog`
in <= 0.15 s (wall, median).

- `status` against no daemon (a socket path nobody listens on: connect, one error line, exit 3)
  and against a running daemon (a `simulate: true` daemon of this checkout on its own socket,
  virtual bus and data folder: the whole answer printed);
- `hold`, `jog X+1`: against no daemon (what they do before they connect);
- `run PROGRAM` (Wang x 100, 48 KB): against no daemon: its start-up, reading the program,
  up to the connection that would submit it.

The interpreter writes and reads bytecode caches here (PYTHONDONTWRITEBYTECODE unset, one
warm-up run per case), as an installed package does; without them every start compiles the
imported modules from source.

Run: python benchmarks/bench_cli_startup.py [--previous-src DIR] [--runs 20]
(``--previous-src``: src/ of a checkout of the previous version, e.g.
``git archive BASE src | tar -x -C /tmp/base`` and ``/tmp/base/src``.)
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_plan_command import wang_copies  # noqa: E402

TARGET_S = 0.15


def child_env(src: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(src)
    return env


def timed(src: Path, args: list[str]) -> tuple[float, float]:
    """(wall s, CPU s) of one `python -m nurbsmotion ARGS` with ``src`` on the path."""
    started = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-m", "nurbsmotion", *args], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, env=child_env(src))
    _, _, usage = os.wait4(child.pid, 0)
    return time.perf_counter() - started, usage.ru_utime + usage.ru_stime


def medians(src: Path, args: list[str], runs: int) -> tuple[float, float]:
    timed(src, args)  # warm-up: bytecode caches written
    results = [timed(src, args) for _ in range(runs)]
    return statistics.median(r[0] for r in results), statistics.median(r[1] for r in results)


def demo_config(work: Path) -> Path:
    """config/demo.yaml on its own socket, virtual channel and data folder (other daemons on
    this machine keep theirs)."""
    text = (ROOT / "config" / "demo.yaml").read_text()
    text = text.replace("socket: /tmp/nurbsmotion.sock", f"socket: {work / 'daemon.sock'}")
    text = text.replace("channel: nurbsmotion-demo", f"channel: bench-startup-{os.getpid()}")
    text = re.sub(r"(?m)^data_dir: .*$", f"data_dir: {work / 'data'}", text)
    path = work / "machine.yaml"
    path.write_text(text)
    return path


def start_daemon(config: Path, socket: Path, timeout_s: float = 60.0) -> subprocess.Popen:
    daemon = subprocess.Popen([sys.executable, "-m", "nurbsmotion", "daemon", "--config", str(config)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=child_env(ROOT / "src"))
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        done = subprocess.run([sys.executable, "-m", "nurbsmotion", "status", "--socket", str(socket)],
                              capture_output=True, env=child_env(ROOT / "src"))
        if done.returncode == 0:
            return daemon
        time.sleep(0.5)
    daemon.terminate()
    raise SystemExit(f"the daemon did not answer on {socket} within {timeout_s:g} s")


def cases(work: Path, socket: Path) -> list[tuple[str, list[str]]]:
    nobody = str(work / "nobody.sock")
    program = work / "wang_x100.nc"
    program.write_text(wang_copies(100))
    return [("`--help`", ["--help"]),
            ("`status`, no daemon", ["status", "--socket", nobody]),
            ("`status`, running daemon", ["status", "--socket", str(socket)]),
            ("`hold`, no daemon", ["hold", "--socket", nobody]),
            ("`jog X+1`, no daemon", ["jog", "X+1", "--socket", nobody]),
            ("`run` Wang x 100, no daemon", ["run", str(program), "--socket", nobody])]


def table(rows: list[tuple[str, tuple[float, float], tuple[float, float] | None]]) -> str:
    lines = ["| command | wall s (median) | CPU s (median) | wall s before | CPU s before | target |",
             "|---|---|---|---|---|---|"]
    for name, (wall, cpu), before in rows:
        old = ("-", "-") if before is None else (f"{before[0]:.3f}", f"{before[1]:.3f}")
        target = "-" if name.startswith("`run`") else f"<= {TARGET_S:g} s ({'met' if wall <= TARGET_S else 'NOT met'} on wall)"
        lines.append(f"| {name} | {wall:.3f} | {cpu:.3f} | {old[0]} | {old[1]} | {target} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--previous-src", type=Path, help="src/ of the previous version: its figures too")
    parser.add_argument("--runs", type=int, default=20)
    args = parser.parse_args()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        socket = work / "daemon.sock"
        daemon = start_daemon(demo_config(work), socket)
        try:
            rows = []
            for name, argv in cases(work, socket):
                now = medians(ROOT / "src", argv, args.runs)
                before = medians(args.previous_src, argv, args.runs) if args.previous_src else None
                rows.append((name, now, before))
                print(name, now, before, flush=True)
        finally:
            daemon.terminate()
            daemon.wait(timeout=30)
    load = os.getloadavg()
    bare = medians(ROOT / "src", ["--version"], args.runs)
    body = (f"Median of {args.runs} runs of each command in a fresh interpreter (`python -m nurbsmotion ...`) "
            "after one warm-up run (bytecode caches written); CPU: the child's user + system time. "
            + ("\"before\": the same commands on the previous version (--previous-src). " if args.previous_src else "")
            + f"`nurbsmotion --version` (the interpreter, argparse and this package's top level): "
              f"{bare[0]:.3f} s wall, {bare[1]:.3f} s CPU.\n\n" + table(rows) + "\n\n"
            f"Load average (1 / 5 / 15 min, `uptime`) {load_before[0]:.1f} / {load_before[1]:.1f} / "
            f"{load_before[2]:.1f} before, {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at the end, on "
            f"{os.cpu_count()} cores shared with other work: wall times on a loaded machine are longer than "
            f"on a quiet one, CPU times less so.\n")
    write_section("cli_startup", "Command start-up", body,
                  "python benchmarks/bench_cli_startup.py --previous-src /tmp/base/src")


if __name__ == "__main__":
    main()
