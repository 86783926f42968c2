"""Run ``nurbsmotion demo`` N times in a row, every other run beside a CPU-burning process,
and count the outcomes (issue 26: "the demo passes 50 runs in a row, 25 of them with a
CPU-burning process beside it; a failed demo leaves no stray job").

    python benchmarks/demo_runs.py --runs 50 --out /tmp/demo-runs      # ~1-2 h on the 2-core host
    python benchmarks/demo_runs.py --out /tmp/demo-runs --report-only --write   # its table into docs/benchmarks.md

Each run is ``nice -n 10 nurbsmotion demo --no-progress --data-dir DIR`` (one data directory
for every run, as a user's ``var/demo``) in a session of its own. After it, a run counts as
passed when the command exited 0 and printed ``outcome: completed``, and as clean when

- every job folder it added to DIR has its ``outcome.json`` (no job left without outcome),
- no process of its session is still alive 10 s after it (the planner worker,
  multiprocessing's resource tracker),
- it left nothing in its temporary directory (``$TMPDIR``, one per run: the demo's socket
  folder, multiprocessing's files).

A line per run goes to ``runs.jsonl`` in --out (with the run's stdout and stderr beside it),
and the table of every run is printed at the end (and on Ctrl-C).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nurbsmotion.runtime import process_stats  # noqa: E402

BURNER = [sys.executable, "-c", "while 1: pass"]
OUTCOME_PREFIX = "outcome: "


@dataclass
class RunResult:
    index: int
    burner: bool
    started_utc: str
    seconds: float
    exit_code: int | None
    outcome: str
    load_before: float
    load_after: float
    jobs_added: int = 0
    jobs_without_outcome: list[str] = field(default_factory=list)
    processes_left: list[str] = field(default_factory=list)
    temp_files_left: list[str] = field(default_factory=list)
    source: str = ""  # --compare-src: the src folder this run's nurbsmotion came from

    @property
    def passed(self) -> bool:
        return self.exit_code == 0 and self.outcome.startswith("completed")

    @property
    def clean(self) -> bool:
        return not (self.jobs_without_outcome or self.processes_left or self.temp_files_left)


def load_average_1min() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def job_folders(data_dir: Path) -> set[Path]:
    jobs = data_dir / "jobs"
    return {p for p in jobs.iterdir() if p.is_dir()} if jobs.is_dir() else set()


def session_members(session_id: int) -> list[int]:
    """Processes whose session id (field 6 of /proc/PID/stat) is ``session_id``."""
    return [pid for pid, _, fields in process_stats() if int(fields[3]) == session_id]


def process_line(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()[:160]
    except OSError:
        return "(ended)"


def processes_left(session_id: int, grace_s: float) -> list[str]:
    """The session's processes still alive ``grace_s`` after its leader ended (a child ending
    with it, such as multiprocessing's resource tracker, gets that long), with their commands."""
    deadline = time.monotonic() + grace_s
    while (members := session_members(session_id)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return [f"pid {pid}: {process_line(pid)}" for pid in members]


def outcome_line(stdout: str) -> str:
    """What follows ``outcome: `` in the demo's report, or the last error line when it has none."""
    for line in stdout.splitlines():
        if line.startswith(OUTCOME_PREFIX):
            return line[len(OUTCOME_PREFIX):]
    return "no outcome line"


def run_once(index: int, burner: bool, command: list[str], data_dir: Path, out: Path, timeout_s: float,
             src: str | None = None) -> RunResult:
    before_jobs, temp_dir = job_folders(data_dir), out / f"tmp{index:02d}"
    temp_dir.mkdir()
    hog = subprocess.Popen(["nice", "-n", "10", *BURNER]) if burner else None
    load_before, started, t0 = load_average_1min(), time.strftime("%H:%M:%S", time.gmtime()), time.monotonic()
    stdout_path, stderr_path = out / f"run{index:02d}.out", out / f"run{index:02d}.err"
    try:
        with open(stdout_path, "w") as so, open(stderr_path, "w") as se:
            proc = subprocess.Popen(command, stdout=so, stderr=se, start_new_session=True,
                                    env={**os.environ, "TMPDIR": str(temp_dir),
                                         **({"PYTHONPATH": src} if src else {})})
            try:
                code: int | None = proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGINT)  # as a user's Ctrl-C: the demo stops its job
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                code = None
    finally:
        if hog is not None:
            hog.kill()
            hog.wait()
    seconds, load_after = time.monotonic() - t0, load_average_1min()
    left = processes_left(proc.pid, grace_s=10.0)
    stdout = stdout_path.read_text(errors="replace")
    if code is None:
        outcome = f"timed out after {timeout_s:g} s"
    else:
        outcome = outcome_line(stdout)
        if outcome == "no outcome line":
            errors = [line for line in stderr_path.read_text(errors="replace").splitlines() if line.strip()]
            outcome = errors[-1] if errors else outcome
    added = job_folders(data_dir) - before_jobs
    return RunResult(index, burner, started, round(seconds, 1), code, outcome, load_before, load_after,
                     jobs_added=len(added),
                     jobs_without_outcome=sorted(p.name for p in added if not (p / "outcome.json").exists()),
                     processes_left=left,
                     temp_files_left=sorted(p.name for p in temp_dir.iterdir()), source=src or "")


def table(results: list[RunResult]) -> str:
    rows = ["| run | version | burner | start (UTC) | s | load 1 min before/after | exit | outcome | jobs | stray |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        stray = ", ".join([*(f"job {j} without outcome" for j in r.jobs_without_outcome),
                           *r.processes_left, *r.temp_files_left]) or "none"
        rows.append(f"| {r.index} | {r.source or '-'} | {'yes' if r.burner else 'no'} | {r.started_utc} | {r.seconds:.0f} | "
                    f"{r.load_before:.1f} / {r.load_after:.1f} | {r.exit_code} | {r.outcome[:120]} | "
                    f"{r.jobs_added} | {stray} |")
    return "\n".join(rows)


def summary(results: list[RunResult]) -> str:
    def count(with_burner: bool) -> str:
        group = [r for r in results if r.burner == with_burner]
        return f"{sum(r.passed for r in group)} of {len(group)}"

    sources = sorted({r.source for r in results})
    if len(sources) > 1:
        return "; ".join(f"{source}: {summary([r for r in results if r.source == source])}" for source in sources)
    loads = [x for r in results for x in (r.load_before, r.load_after)]
    load = f"load {min(loads):.1f}-{max(loads):.1f}" if loads else "no run"
    return (f"passed {sum(r.passed for r in results)} of {len(results)} (quiet {count(False)}, burner {count(True)}); "
            f"clean {sum(r.clean for r in results)} of {len(results)}; {load}")


def read_results(path: Path) -> list[RunResult]:
    """The runs of an earlier (or still running) series from its runs.jsonl."""
    names = set(RunResult.__dataclass_fields__)
    return [RunResult(**{k: v for k, v in json.loads(line).items() if k in names})
            for line in path.read_text().splitlines() if line.strip()]


def write_doc(results: list[RunResult], command: str) -> None:
    """docs/benchmarks.md, section demo_runs: the summary; docs/benchmarks/demo_runs.md: the table of every run."""
    from benchmarks._report import write_section

    how = ("Every run `nice -n 10 nurbsmotion demo --no-progress --data-dir DIR` (one DIR for "
           "all, its own TMPDIR each), even runs beside `nice -n 10 python3 -c 'while 1: pass'`; the host's load "
           "is mostly other helpers' work. A run passes when it exits 0 with `outcome: completed`; it is "
           "clean when it leaves no job without outcome.json, no process of its session 10 s after it and "
           "nothing in its TMPDIR.")
    write_section("demo_runs", "`nurbsmotion demo`, run after run", f"{summary(results)}.", command,
                  detail=f"{summary(results)}. {how}\n\n" + table(results))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--out", type=Path, required=True, help="folder for runs.jsonl, the outputs and data/")
    parser.add_argument("--timeout-s", type=float, default=600.0, help="a run that takes longer counts as failed")
    parser.add_argument("--nurbsmotion", default=str(Path(sys.executable).with_name("nurbsmotion")))
    parser.add_argument("--stop-on-failure", action="store_true")
    parser.add_argument("--compare-src", metavar="DIR", help="every other pair of runs with DIR/src first on the "
                                                                 "path (another version, e.g. a git archive): interleaved")
    parser.add_argument("--report-only", action="store_true", help="no run: the table of --out's runs.jsonl")
    parser.add_argument("--write", action="store_true", help="the table into docs/benchmarks.md (section demo_runs)")
    args = parser.parse_args(argv)
    # Started in the background (nohup, `&`), this process ignores SIGINT and its demos would
    # inherit that (flake 6 in docs/reliability.md): a handled SIGINT is the default in a child.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    args.out.mkdir(parents=True, exist_ok=True)
    data_dir = args.out / "data"
    command = ["nice", "-n", "10", args.nurbsmotion, "demo", "--no-progress", "--data-dir", str(data_dir)]
    if args.compare_src:  # both versions as `python -m nurbsmotion`, the one on PYTHONPATH first
        command = ["nice", "-n", "10", sys.executable, "-m", "nurbsmotion", "demo", "--no-progress", "--data-dir",
                   str(data_dir)]
    sources = [str(Path(__file__).resolve().parents[1] / "src"), str(Path(args.compare_src or ".") / "src")]
    results: list[RunResult] = read_results(args.out / "runs.jsonl") if args.report_only else []
    try:
        for index in range(1, 0 if args.report_only else args.runs + 1):
            src = sources[(index - 1) // 2 % 2] if args.compare_src else None
            result = run_once(index, index % 2 == 0, command, data_dir, args.out, args.timeout_s, src)
            results.append(result)
            with open(args.out / "runs.jsonl", "a") as log:
                log.write(json.dumps({**asdict(result), "passed": result.passed, "clean": result.clean}) + "\n")
            print(f"run {index}: {'pass' if result.passed else 'FAIL'}{'' if result.clean else ' (stray)'} "
                  f"{result.seconds:.0f} s, burner {result.burner}, load {result.load_before:.1f}: {result.outcome}",
                  flush=True)
            if args.stop_on_failure and not (result.passed and result.clean):
                break
    except KeyboardInterrupt:
        print("interrupted", flush=True)
    print(table(results))
    print(summary(results))
    if args.write:
        write_doc(results, f"python benchmarks/demo_runs.py --runs {len(results)} --out DIR --write")
    return 0 if results and all(r.passed and r.clean for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
