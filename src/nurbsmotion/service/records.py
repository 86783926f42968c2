"""Job records: one folder per job under ``<data_dir>/jobs/<YYYYmmdd-HHMMSS.mmm>-<id>/`` (the
time of the submission to the millisecond, so the folders sort in submission order).

Written in the order that loses nothing when a job ends badly: the program as submitted, the
configuration in force and the plan (summary + trace) before any motion, the drives'
feedback while the job runs, ``outcome.json`` when the job has ended. A job folder without
an outcome belongs to a daemon that died; the next daemon marks it ``interrupted`` at start.
A submission whose program is rejected leaves a folder too: the program and an outcome
``rejected`` with its error lines. Every JSON file is written to a temporary name, flushed
and renamed.
"""

from __future__ import annotations

import json
import os
import re
import uuid
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Callable, Iterable

from nurbsmotion.errors import InputError
from nurbsmotion.service.program_file import ProgramFile

PROGRAM_FILE = "program"  # suffix added from the submitted name (.nc, .yaml ...)
PLAN_FILE = "plan.json"
TRACE_FILE = "trace.csv"
OUTCOME_FILE = "outcome.json"
DRIVES_DIR = "drives"  # simulated drives' set-point recordings (simulate: true)
TRAFFIC_FILE = "traffic"  # + .log / .asc: every bus frame of the job (monitoring.traffic_log)
CONFIG_FILE = "config.json"  # the machine configuration the job ran with (defaults filled in)
FEEDBACK_FILE = "feedback.csv"  # every TPDO1 of the job: statusword and position actual (service.feedback)
BLOCK_LINES_FILE = "blocks.csv"  # the program line of each block (row i: block i), before motion
FEEDBACK_TAIL_BYTES = 1 << 16  # feedback.csv grows ~120 kB per second of motion: only its end is read
REACHED_NOTE = "from the record's files: the last job cycle and positions actual in feedback.csv, that row of trace.csv"
OUTCOMES = ("completed", "stopped", "aborted", "fault", "interrupted", "rejected")


def new_job_id() -> str:
    return uuid.uuid4().hex[:8]


def now_iso() -> str:
    """Local wall-clock time with milliseconds and UTC offset (2026-11-24T10:12:03.250+00:00)."""
    return datetime.now().astimezone().isoformat(timespec="milliseconds")


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` so that ``path`` holds either the old or the complete new content."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as out:
        out.write(data)
        out.flush()
        os.fsync(out.fileno())
    os.replace(tmp, path)


def write_json(path: Path, obj: dict[str, Any]) -> None:
    write_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode("utf-8"))


def whole_rows(path: Path) -> int:
    """Data rows of a CSV with one header line, cut after its last complete line (a file
    whose writer was killed may end mid-line)."""
    with open(path, "rb+") as csv:
        data = csv.read()
        end = data.rfind(b"\n") + 1
        csv.truncate(end)
    return max(data[:end].count(b"\n") - 1, 0)


def _safe_suffix(name: str) -> str:
    suffix = Path(name).suffix.lower()
    return suffix if re.fullmatch(r"\.[a-z0-9]{1,8}", suffix) else ".txt"


@dataclass(frozen=True)
class JobRecord:
    job_id: str
    folder: Path

    def write_program(self, name: str, text: str | ProgramFile) -> Path:
        """The program as submitted: its text written, or its file linked (service.program_file)."""
        path = self.folder / f"{PROGRAM_FILE}{_safe_suffix(name)}"
        if isinstance(text, ProgramFile):
            text.link_to(path)
        else:
            write_atomic(path, text.encode("utf-8"))
        return path

    def write_plan(self, summary: dict[str, Any], write_trace: Callable[[Path], None]) -> None:
        """The plan summary and the trace CSV (``write_trace(path)`` writes it)."""
        tmp = self.folder / f".{TRACE_FILE}.tmp"
        write_trace(tmp)
        os.replace(tmp, self.folder / TRACE_FILE)
        write_json(self.folder / PLAN_FILE, summary)

    def write_plan_summary(self, summary: dict[str, Any]) -> None:
        """plan.json alone (a streamed job: written before motion, then again at its end)."""
        write_json(self.folder / PLAN_FILE, summary)

    def complete_streamed_plan(self) -> int | None:
        """A streamed job whose daemon died: its trace (``trace.csv.part``, written as it was
        planned) cut to whole rows and named trace.csv, and plan.json's ``cycles`` set to its
        rows, so the record holds what was planned (None: nothing to complete)."""
        plan_path = self.folder / PLAN_FILE
        try:
            plan = json.loads(plan_path.read_text())
        except (OSError, ValueError):
            return None
        if not plan.get("streamed") or plan.get("cycles") is not None:
            return None
        rows = self.adopt_trace_part()
        plan.update({"cycles": rows, "planned_all": False,
                     "duration_s": round(max(rows - 1, 0) * float(plan.get("period_s", 0.0)), 6),
                     "cycles_note": "the trace rows planned before the daemon ended"})
        write_json(plan_path, plan)
        return rows

    def adopt_trace_part(self) -> int:
        """The trace its writer left unfinished (``trace.csv.part``: killed) cut to whole rows
        and named trace.csv; the trace's data rows (0 when there is none)."""
        part = self.folder / f"{TRACE_FILE}.part"
        trace = part if part.exists() else self.folder / TRACE_FILE
        if not trace.exists():
            return 0
        rows = whole_rows(trace)
        if trace == part:
            os.replace(part, self.folder / TRACE_FILE)
        return rows

    def write_block_lines(self, lines: Iterable[int]) -> None:
        """blocks.csv: the program line of each block, so an interrupted job's record can name
        the line it reached without reading the program again."""
        write_atomic(self.folder / BLOCK_LINES_FILE, ("line\n" + "".join(f"{n}\n" for n in lines)).encode("ascii"))

    def reached_when_interrupted(self) -> dict[str, Any]:
        """``line_reached`` and ``final_position`` of a job whose daemon died, from its files:
        the last job cycle feedback.csv holds (what the drives reported last), that row of
        trace.csv (its set-points and block; blocks.csv names the block's line) and each axis'
        last position actual. Empty when the files do not tell (no feedback, no motion yet)."""
        feedback = last_feedback(self.folder / FEEDBACK_FILE)
        if feedback is None or feedback[0] < 0:
            return {}
        cycle, actual_mm = feedback
        row = trace_row(self.folder / TRACE_FILE, cycle)
        if row is None:
            return {}
        index, values = row
        final = {name: {"commanded_mm": float(values[name.lower()]) if name.lower() in values else None,
                        "actual_mm": position} for name, position in actual_mm.items()}
        out: dict[str, Any] = {"final_position": final, "settled": False, "reached_from": REACHED_NOTE}
        line = nth_line(self.folder / BLOCK_LINES_FILE, int(float(values.get("block", -1))) + 1)
        if line is not None and line.isdigit():
            name = (self.plan() or {}).get("program") or self._program_name()
            program = next(self.folder.glob(f"{PROGRAM_FILE}.*"), None)
            text = nth_line(program, int(line) - 1) if program is not None else None
            out["line_reached"] = {"where": f"{name}:{line}", "line": int(line), "text": (text or "").strip(),
                                   "block": int(float(values["block"])), "setpoint": index}
        return out

    def write_config(self, config: dict[str, Any]) -> None:
        write_json(self.folder / CONFIG_FILE, config)

    def write_outcome(self, outcome: dict[str, Any]) -> None:
        if outcome.get("outcome") not in OUTCOMES:
            raise ValueError(f"unknown outcome {outcome.get('outcome')!r}")
        write_json(self.folder / OUTCOME_FILE, outcome)

    def outcome(self) -> dict[str, Any] | None:
        try:
            return json.loads((self.folder / OUTCOME_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def plan(self) -> dict[str, Any] | None:
        try:
            return json.loads((self.folder / PLAN_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    @property
    def drives_dir(self) -> Path:
        return self.folder / DRIVES_DIR

    @property
    def feedback_path(self) -> Path:
        return self.folder / FEEDBACK_FILE

    @property
    def created_at(self) -> str:
        """The folder's time stamp (the submission), as ``YYYY-mm-ddTHH:MM:SS.mmm``."""
        stamp = self.folder.name.rsplit("-", 1)[0]
        for form in ("%Y%m%d-%H%M%S.%f", "%Y%m%d-%H%M%S"):  # older records: whole seconds
            try:
                return datetime.strptime(stamp, form).isoformat(timespec="milliseconds")
            except ValueError:
                continue
        return ""

    def summary(self) -> dict[str, Any]:
        """One line of ``jobs``: id, name, submitted, outcome (None while it runs), line reached."""
        outcome = self.outcome() or {}
        plan = self.plan() or {}
        reached = outcome.get("line_reached") or {}
        return {"id": self.job_id, "name": outcome.get("name") or plan.get("program") or self._program_name(),
                "submitted_at": self.created_at, "outcome": outcome.get("outcome"),
                "reason": outcome.get("reason", ""), "line_reached": reached.get("where"),
                "motion_time_s": outcome.get("motion_time_s"), "folder": str(self.folder)}

    def _program_name(self) -> str:
        return next((p.name for p in self.folder.glob(f"{PROGRAM_FILE}.*")), "")


class JobRecords:
    """The ``jobs`` folder of the data directory."""

    def __init__(self, data_dir: str | Path) -> None:
        self.root = Path(data_dir).absolute() / "jobs"  # shown to clients, whose working directory is not ours
        self._last_stamp_ms = 0  # folder stamps strictly increase, so names sort in submission order

    def _next_stamp(self) -> datetime:
        """Now to the millisecond, or 1 ms after the previous record's stamp if that is not earlier."""
        stamp_ms = max(int(datetime.now().timestamp() * 1000), self._last_stamp_ms + 1)
        self._last_stamp_ms = stamp_ms
        return datetime.fromtimestamp(stamp_ms // 1000).replace(microsecond=stamp_ms % 1000 * 1000)

    def create(self, name: str, text: str | ProgramFile) -> JobRecord:
        """A new job folder holding the program as submitted."""
        self.root.mkdir(parents=True, exist_ok=True)
        job_id = new_job_id()
        now = self._next_stamp()
        folder = self.root / f"{now:%Y%m%d-%H%M%S}.{now.microsecond // 1000:03d}-{job_id}"
        folder.mkdir()
        record = JobRecord(job_id, folder)
        record.write_program(name, text)
        return record

    def create_rejected(self, name: str, text: str | ProgramFile, errors: list[str]) -> JobRecord:
        """The record of a submission whose program was rejected: the program and why."""
        record = self.create(name, text)
        record.write_outcome({"outcome": "rejected", "job": record.job_id, "name": name, "reason": errors[0],
                              "errors": errors, "recorded_at": now_iso()})
        return record

    def all(self) -> list[JobRecord]:
        """Every record, oldest first (folder names start with the submission time)."""
        if not self.root.is_dir():
            return []
        return [JobRecord(p.name.rsplit("-", 1)[-1], p) for p in sorted(self.root.iterdir())
                if p.is_dir() and "-" in p.name]

    def find(self, job_id: str) -> JobRecord | None:
        if not re.fullmatch(r"[0-9a-f]{1,32}", job_id) or not self.root.is_dir():
            return None
        for folder in self.root.glob(f"*-{job_id}"):
            return JobRecord(job_id, folder)
        return None

    def info(self, job_id: str, running_id: str | None = None) -> dict[str, Any]:
        """One record in full (the ``job`` response); InputError for an unknown id."""
        record = self.find(job_id)
        if record is None:
            raise InputError("field 'id'", f"no job {job_id!r} in {self.root}")
        running = job_id == running_id
        return {"id": job_id, "folder": str(record.folder), "running": running, "submitted_at": record.created_at,
                "plan": record.plan(), "outcome": None if running else record.outcome(),
                "files": sorted(p.name for p in record.folder.iterdir() if not p.name.startswith("."))}

    def listing(self, limit: int = 20, running_id: str | None = None) -> dict[str, Any]:
        """The newest ``limit`` records, newest first (the ``jobs`` response)."""
        if limit < 1:
            raise InputError("field 'limit'", f"must be at least 1, got {limit:g}")
        records = self.all()
        rows = [{**r.summary(), "running": r.job_id == running_id} for r in reversed(records[-int(limit):])]
        return {"jobs": rows, "total": len(records), "root": str(self.root)}

    def mark_interrupted(self) -> list[JobRecord]:
        """Give every job folder without an outcome the outcome 'interrupted'."""
        marked = []
        for record in self.all():
            if not (record.folder / OUTCOME_FILE).exists():
                record.complete_streamed_plan()
                record.write_outcome({"outcome": "interrupted", "job": record.job_id,
                                      "reason": "the daemon ended while this job was in progress",
                                      "recorded_at": now_iso(), "line_reached": None, "final_position": None,
                                      **record.reached_when_interrupted()})
                marked.append(record)
        return marked


def last_feedback(path: Path) -> tuple[int, dict[str, float]] | None:
    """The last job cycle in feedback.csv and each axis' last position actual (mm) there, read
    from the file's end; None without feedback."""
    try:
        with open(path, "rb") as csv:
            size = csv.seek(0, os.SEEK_END)
            csv.seek(max(size - FEEDBACK_TAIL_BYTES, 0))
            lines = csv.read().split(b"\n")
    except OSError:
        return None
    cycle, positions = -1, {}
    for raw in lines[1 if size > FEEDBACK_TAIL_BYTES else 0:-1]:  # whole lines: the tail's first and the last may be cut
        fields = raw.split(b",")
        try:
            job_cycle, axis, position_mm = int(fields[0]), fields[1].decode("ascii"), float(fields[5])
        except (IndexError, ValueError, UnicodeDecodeError):
            continue  # the header, a line cut by the daemon's death
        cycle, positions[axis] = max(cycle, job_cycle), position_mm
    return (cycle, positions) if positions else None


def trace_row(path: Path, index: int) -> tuple[int, dict[str, str]] | None:
    """(row index, {column: value}) of row ``index`` of a trace CSV, or its last whole row if
    it has fewer; None if it has none."""
    try:
        with open(path, encoding="ascii", errors="replace") as csv:
            header = csv.readline().strip().split(",")
            found: tuple[int, str] | None = None
            for i, line in enumerate(csv):
                if not line.endswith("\n"):
                    break
                found = (i, line)
                if i >= index:
                    break
    except OSError:
        return None
    return (found[0], dict(zip(header, found[1].strip().split(",")))) if found is not None else None


def nth_line(path: Path, index: int) -> str | None:
    """Line ``index`` (0: the first) of a text file, None if it has fewer or cannot be read."""
    if index < 0:
        return None
    try:
        with open(path, encoding="utf-8", errors="replace") as text:
            for i, line in enumerate(text):
                if i == index:
                    return line.rstrip("\n")
    except OSError:
        return None
    return None
