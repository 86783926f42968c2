"""``nurbsmotion run PROGRAM``: submit a program to the daemon, show progress, print the outcome.

Exit codes: 0 completed, 1 stopped/aborted/fault, 2 rejected (errors one per line, file:line),
3 no daemon. Ctrl-C asks the daemon for a controlled stop; a second Ctrl-C leaves the job running.
The feed override starts at 100 % unless ``--keep-override``. If the daemon ends while the
job runs, the outcome is read from the job's record (when this user may read it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, BinaryIO, Callable

from nurbsmotion.cli._control import EXIT_REFUSED, add_socket_arguments, error_line, with_client
from nurbsmotion.cli._format import figure, number, reading_text
from nurbsmotion.service.client import Client, DaemonUnavailable, RequestFailed
from nurbsmotion.service.records import OUTCOME_FILE, PLAN_FILE
from nurbsmotion.text_files import open_text_file, read_text_file

HELP = "submit a program (G-code or YAML) to the daemon, follow it and print the outcome"
POLL_S = 0.2
PLAIN_EVERY_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("program", help="program file (.nc G-code or .yaml curves); checked here, the open file "
                                         "sent to the daemon (its text to a daemon that cannot take files)")
    add_job_options(parser)
    add_socket_arguments(parser)


def add_job_options(parser: argparse.ArgumentParser) -> None:
    """The options of a job started by ``run`` and by ``start``."""
    parser.add_argument("--no-progress", action="store_true", help="only print the outcome")
    parser.add_argument("--keep-override", action="store_true",
                        help="keep the feed override in force now (default: the job starts at 100 %%)")
    parser.add_argument("--no-block-delete", action="store_true", help="run '/' lines (block delete switch off)")
    parser.add_argument("--no-optional-stop", action="store_true", help="M1 does not pause (optional stop switch off)")
    parser.add_argument("--start-line", type=line_number, metavar="N",
                        help="start from line N: the state there rebuilt, approached over machine.safe_z_mm")


def line_number(text: str) -> int:
    """argparse type of --start-line: a whole number >= 1."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"must be a line number >= 1, got {text!r}")
    return int(text)


def progress_text(status: dict[str, Any]) -> str:
    job = status["job"]
    positions = " ".join(f"{a['name']} {number(a['commanded_mm'], 3)}" for a in status["axes"])
    return (f"{figure(job['percent'], '5.1f')} %  cycle {job['cycle']}/{job['total']}  "
            f"feed {number(job['feed_mm_s'], 1)} mm/s  override {figure(job['override_percent'], 'g')} %  "
            f"{job.get('line') or '-'}  {positions}  [{_state_text(status)}]")


def _state_text(status: dict[str, Any]) -> str:
    """'running', 'held', or 'held: M6 tool change to T3 at part.nc:20 (resume to continue)'."""
    paused = (status.get("job") or {}).get("paused")
    return f"{status['state']}: {paused} (resume to continue)" if status["state"] == "held" and paused else \
        status["state"]


class _Plain:
    """One line per second when the output is not a terminal."""

    def __init__(self) -> None:
        self.last = 0.0

    def update(self, status: dict[str, Any]) -> None:
        now = time.monotonic()
        if now - self.last >= PLAIN_EVERY_S:
            self.last = now
            print(progress_text(status), flush=True)

    def close(self) -> None:
        pass


class _Rich:
    """A rich progress bar with feed and position (when rich is installed and stdout is a TTY)."""

    def __init__(self, name: str) -> None:
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        self.progress = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>5.1f} %"),
                                 TimeRemainingColumn(), TextColumn("{task.fields[info]}"))
        self.task = self.progress.add_task(name, total=1, info="")
        self.progress.start()

    def update(self, status: dict[str, Any]) -> None:
        job = status["job"]
        positions = " ".join(f"{a['name']}{figure(a['commanded_mm'], '+.2f')}" for a in status["axes"])
        self.progress.update(self.task, total=job["total"], completed=job["cycle"],
                             info=f"{figure(job['feed_mm_s'], '6.1f')} mm/s ovr {figure(job['override_percent'], 'g')} % "
                                  f"{job.get('line') or '-'} {positions} {_state_text(status)}")

    def close(self) -> None:
        self.progress.stop()


def _display(name: str, quiet: bool) -> Any:
    if quiet:
        return None
    if sys.stdout.isatty():
        try:
            return _Rich(name)
        except ImportError:
            pass
    return _Plain()


def follow(client: Client, job_id: str, on_status: Callable[[dict[str, Any]], None] | None) -> dict[str, Any]:
    """Poll the status until job ``job_id`` has ended; return its record (with outcome)."""
    stop_sent = False
    while True:
        try:
            status = client.call("status")
            job = status.get("job")
            if job is None or job["id"] != job_id:
                return client.call("job", id=job_id)["job"]
            if on_status is not None:
                on_status(status)
            time.sleep(POLL_S)
        except KeyboardInterrupt:
            if stop_sent:
                raise
            stop_sent = True
            sys.stderr.write("stopping the job along the path (Ctrl-C again to leave it running)\n")
            client.request("stop")


def describe_outcome(info: dict[str, Any]) -> str:
    outcome = info.get("outcome") or {}
    text = (f"job {info['id']} {outcome.get('outcome', 'unknown')}: {figure(outcome.get('sent'))}/"
            f"{figure(outcome.get('planned'))} set-points in {number(outcome.get('motion_time_s'), 2)} s")
    reached = outcome.get("line_reached")
    if reached and outcome.get("outcome") != "completed":
        text += f", reached {reached['where']}"
    if outcome.get("reason"):
        text += f"; {outcome['reason']}"
    return f"{text}\nrecord: {info['folder']}"


def record_read_here(job: dict[str, Any]) -> dict[str, Any] | None:
    """The job's record read from its folder (the daemon is gone); None if it has no outcome
    yet or this user may not read it."""
    folder = Path(job["folder"])
    try:
        outcome = json.loads((folder / OUTCOME_FILE).read_text(encoding="utf-8"))
        plan = json.loads((folder / PLAN_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return {"id": job["id"], "folder": str(folder), "plan": plan, "outcome": outcome}


def follow_to_the_end(client: Client, job: dict[str, Any], display: Any) -> dict[str, Any] | None:
    """follow(); when the daemon ends meanwhile, the outcome from the record (None: unknown)."""
    try:
        return follow(client, job["id"], display.update if display else None)
    except (DaemonUnavailable, RequestFailed):
        deadline = time.monotonic() + 2.0  # the daemon writes the outcome before it lets go of the socket
        while time.monotonic() < deadline:
            info = record_read_here(job)
            if info is not None:
                return info
            time.sleep(POLL_S)
        return None


def start_and_follow(client: Client, args: argparse.Namespace, title: str, cmd: str, fields: dict[str, Any],
                     program: BinaryIO | None = None) -> int:
    """Send ``cmd`` (submit, start, mdi; with the ``program`` file: program_request), follow
    the job it started with a progress display, print its outcome; the exit code (0
    completed, 1 not, 2 rejected)."""
    response = client.request(cmd, **fields) if program is None else program_request(client, cmd, fields, program)
    if not response.get("ok"):
        for line in response.get("errors") or [response.get("error", "rejected")]:
            error_line(args, line)
        return EXIT_REFUSED
    read = reading_text(response["job"]["summary"].get("reading")) if cmd in ("submit", "start") else None
    if cmd == "start" and response["job"]["summary"].get("checked_from_store"):
        print(f"{title}: checked before (the library's check of it holds)", flush=True)
    if read:  # as check says it: a program read only in part is never silent
        print(f"{title}: {response['job']['summary'].get('blocks')} blocks, lines {read}", flush=True)
    info = follow_and_report(client, args, response["job"], _display(title, args.no_progress), "job")
    return 0 if info is not None and (info.get("outcome") or {}).get("outcome") == "completed" else 1


def follow_and_report(client: Client, args: argparse.Namespace, job: dict[str, Any], display: Any,
                      noun: str) -> dict[str, Any] | None:
    """Follow ``job`` to its end with ``display`` (closed after), print its outcome; None (said
    on stderr, naming its record) when the daemon ended meanwhile."""
    try:
        info = follow_to_the_end(client, job, display)  # Ctrl-C: stop along the path
    finally:
        if display is not None:
            display.close()
    if info is None:
        error_line(args, f"the daemon ended while {noun} {job['id']} ran; its record: {job['folder']}")
        return None
    print(describe_outcome(info))
    return info


def program_request(client: Client, cmd: str, fields: dict[str, Any], program: BinaryIO) -> dict[str, Any]:
    """``cmd`` with the open ``program`` file passed along (protocol ``program_fd``: the daemon
    reads it from the descriptor, whoever may read its path); a daemon that takes no files
    (an older one) gets its text."""
    response = client.request(cmd, files=[program.fileno()], program_fd=0, **fields)
    if not response.get("ok") and str(response.get("error", "")).startswith("field 'program_fd'"):
        response = client.request(cmd, program=read_text_file(program.name), **fields)
    return response


def run(args: argparse.Namespace) -> int:
    program = open_text_file(args.program)  # the same errors as check's

    def body(client: Client) -> int:
        name = Path(args.program).name
        return start_and_follow(client, args, name, "submit", {"name": name, **job_fields(args)}, program)

    with program:
        return with_client(args, body)


def job_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The request fields of add_job_options' options (only those not at their default)."""
    fields: dict[str, Any] = {"keep_override": True} if args.keep_override else {}
    fields.update({k: False for k, off in (("block_delete", args.no_block_delete),
                                            ("optional_stop", args.no_optional_stop)) if off})
    if args.start_line is not None:
        fields["start_line"] = args.start_line
    return fields
