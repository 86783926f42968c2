"""The persistent job queue (issue 22 part 5): library programs that run one after another.

DATA_DIR/queue.json holds the entries in order (id, program, start line, when added) and
whether the queue is paused and why; every change is written atomically before it is
answered. The :class:`QueueRunner` thread (normal priority, every POLL_S) starts the first
entry when the machine is idle and the queue is not paused: through the library's ``start``,
so each program is still checked before motion (the checked-program store makes that cheap).

The queue pauses itself, and the operator resumes it explicitly (``queue.resume``):
- when a job it started ends in anything but ``completed`` (fault, abort, stop);
- when its next program is refused (rejected, not homed, busy with another job): the entry
  stays first;
- when the drives are in fault while it waits (a reset does not start the next entry);
- at the daemon's start when it holds entries: a restart never starts motion by itself.
Every change is one INFO log line ``queue_changed`` (an event on the subscribe push).
"""

from __future__ import annotations

import json
import logging
import threading
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.service.program_library import check_library_name, write_atomically
from nurbsmotion.service.records import now_iso

log = logging.getLogger(__name__)

QUEUE_FILE = "queue.json"
POLL_S = 0.25
RESTARTED = "the daemon restarted: resume the queue to go on"


@dataclass(frozen=True)
class QueueEntry:
    id: int
    program: str
    start_line: int | None = None
    added_at: str = field(default_factory=now_iso)


class JobQueue:
    """The entries and the pause, kept in DATA_DIR/queue.json (module docstring)."""

    def __init__(self, data_dir: str | Path) -> None:
        self.path = Path(data_dir) / QUEUE_FILE
        self.entries: list[QueueEntry] = []
        self.paused: str | None = None  # why it is paused; None: it runs when the machine is idle
        self.next_id = 1
        self.lock = threading.RLock()
        self._load()

    def _load(self) -> None:
        """The queue as it was; InputError naming the file when it cannot be read."""
        try:
            doc = json.loads(self.path.read_text())
            self.entries = [QueueEntry(int(e["id"]), check_library_name(str(e["program"])),
                                       None if e.get("start_line") is None else int(e["start_line"]),
                                       str(e.get("added_at", ""))) for e in doc["entries"]]
            self.next_id = max([int(doc.get("next_id", 1))] + [e.id + 1 for e in self.entries])
            self.paused = doc.get("paused")
        except FileNotFoundError:
            return
        except (OSError, ValueError, KeyError, TypeError, InputError) as err:
            raise InputError(str(self.path), f"the job queue cannot be read ({err}); move it away to start "
                                             "with an empty queue") from None
        if self.entries and self.paused is None:
            self.paused = RESTARTED

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            return {"entries": [asdict(e) for e in self.entries], "paused": self.paused}

    def summary(self) -> dict[str, Any]:
        """For the status: how many wait, the next, whether paused (and why)."""
        with self.lock:
            return {"entries": len(self.entries), "next": self.entries[0].program if self.entries else None,
                    "paused": self.paused}

    def add(self, program: str, start_line: int | None = None) -> QueueEntry:
        with self.lock:
            entry = QueueEntry(self.next_id, check_library_name(program), start_line)
            self.next_id += 1
            self.entries.append(entry)
            self._changed("add", entry.id, program=program)
            return entry

    def remove(self, entry_id: int) -> QueueEntry:
        with self.lock:
            entry = self._entry(entry_id)
            self.entries.remove(entry)
            self._changed("remove", entry_id, program=entry.program)
            return entry

    def move(self, entry_id: int, position: int) -> None:
        """Put the entry at ``position`` (1 = first; beyond the end = last)."""
        if position < 1:
            raise InputError("field 'position'", f"must be 1 or more (1 = first), got {position}")
        with self.lock:
            entry = self._entry(entry_id)
            self.entries.remove(entry)
            self.entries.insert(min(position, len(self.entries) + 1) - 1, entry)
            self._changed("move", entry_id, position=position)

    def clear(self) -> int:
        with self.lock:
            count = len(self.entries)
            self.entries.clear()
            self._changed("clear", None, removed=count)
            return count

    def pause(self, reason: str) -> None:
        with self.lock:
            if self.paused != reason:
                self.paused = reason
                self._changed("pause", None, reason=reason)

    def resume(self) -> None:
        with self.lock:
            self.paused = None
            self._changed("resume", None)

    def take_first(self) -> QueueEntry | None:
        """The first entry, removed (None when paused or empty)."""
        with self.lock:
            if self.paused is not None or not self.entries:
                return None
            entry = self.entries.pop(0)
            self._changed("start", entry.id, program=entry.program)
            return entry

    def put_back(self, entry: QueueEntry, reason: str) -> None:
        """``entry`` first again and the queue paused: its start was refused for ``reason``."""
        with self.lock:
            self.entries.insert(0, entry)
            self.paused = reason
            self._changed("refused", entry.id, program=entry.program, reason=reason)

    def _entry(self, entry_id: int) -> QueueEntry:
        found = next((e for e in self.entries if e.id == entry_id), None)
        if found is None:
            ids = ", ".join(str(e.id) for e in self.entries) or "none"
            raise InputError("field 'id'", f"no queue entry {entry_id} (entries: {ids})")
        return found

    def _changed(self, action: str, entry_id: int | None, **fields: Any) -> None:
        """Write the file (InputError naming data_dir when it cannot be), then one log line."""
        doc = {"next_id": self.next_id, "paused": self.paused, "entries": [asdict(e) for e in self.entries]}
        try:
            write_atomically(self.path, json.dumps(doc, indent=1).encode())
        except OSError as err:
            raise InputError("data_dir", f"cannot write the job queue {self.path}: {err.strerror or err}") from None
        log.info(kv("queue_changed", action=action, id=entry_id if entry_id is not None else "-",
                    entries=len(self.entries), paused=self.paused or "-", **fields))


@dataclass
class QueueHooks:
    """What the runner needs of the daemon: is the machine idle, start an entry (the job's
    id, or InputError), the last job's id and outcome, is it in fault."""

    idle: Callable[[], bool]
    start: Callable[[QueueEntry], str]
    last_job: Callable[[], dict[str, Any] | None]
    faulted: Callable[[], bool] = lambda: False


class QueueRunner:
    """Starts the queue's entries one after another (module docstring)."""

    def __init__(self, queue: JobQueue, hooks: QueueHooks, poll_s: float = POLL_S) -> None:
        self.queue = queue
        self.hooks = hooks
        self.poll_s = poll_s
        self.waiting_for: str | None = None  # the job id the queue started last, until it ended
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="job-queue", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            try:
                self.step()
            except Exception:  # noqa: BLE001 - the queue must not end the daemon
                log.exception("job queue step failed")
                self.queue.pause("internal error in the job queue (see the daemon's log)")

    def step(self) -> None:
        """One look: judge the job the queue started once it ended; start the next when idle."""
        if self.waiting_for is not None:
            last = self.hooks.last_job()
            if last is None or last.get("id") != self.waiting_for:
                return
            self.waiting_for = None
            if last.get("outcome") != "completed":
                self.queue.pause(f"job {last['id']} ({last.get('name')}) ended {last.get('outcome')}"
                                 f"{': ' + last['reason'] if last.get('reason') else ''}")
                return
        if self.queue.paused is not None or not self.queue.entries:
            return
        if self.hooks.faulted():
            self.queue.pause("the drives are in fault: reset, then resume the queue")
            return
        if not self.hooks.idle():
            return
        entry = self.queue.take_first()
        if entry is None:
            return
        try:
            self.waiting_for = self.hooks.start(entry)
        except InputError as err:
            self.queue.put_back(entry, f"{entry.program} refused: {str(err).splitlines()[0]}")
