"""The daemon's program library and job queue requests (``programs.*``, ``start``, ``queue.*``).

- ``programs.add``: the name and size checked, the program read and checked as a job started
  now would be (service.program_check, in the checker process), then kept in the library
  (service.program_library) with its report; a refused program is not added (its errors,
  file:line each, as a rejected submit's);
- ``start NAME``: the library's text submitted as ``run`` submits a file, with the same
  options; the planner worker finds it checked in the store (service.checked_store) when
  nothing its check depends on changed, and reads and checks it again otherwise;
- ``queue.*``: the persistent queue (service.job_queue) and its runner thread.
"""

from __future__ import annotations

import logging
from typing import Any, Callable

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.service.checked_store import CheckedStore, text_digest
from nurbsmotion.service.controller import Controller
from nurbsmotion.service.job_queue import JobQueue, QueueEntry, QueueHooks, QueueRunner
from nurbsmotion.service.planner_worker import as_error
from nurbsmotion.service.program_check import ProgramChecker
from nurbsmotion.service.program_file import ProgramFile, requested_program
from nurbsmotion.service.program_library import ProgramLibrary, check_library_name
from nurbsmotion.service.protocol import Request
from nurbsmotion.service.start_line import start_line_field

log = logging.getLogger(__name__)

LIBRARY_COMMANDS = frozenset({"programs.add", "programs.list", "programs.get", "programs.remove", "start", "queue.list",
                              "queue.add", "queue.remove", "queue.move", "queue.clear", "queue.pause",
                              "queue.resume"})  # served by Programs.handlers


class Programs:
    """The library, the checked-program store, the checker and the queue of one daemon."""

    def __init__(self, config: MachineConfig, controller: Controller, store: CheckedStore, queue: JobQueue) -> None:
        self.config = config
        self.controller = controller
        self.store = store
        self.library = ProgramLibrary(config.data_dir, config.web.max_upload_mb)
        self.checker = ProgramChecker()
        self.queue = queue
        self.runner = QueueRunner(self.queue, QueueHooks(controller.idle, self._start_entry, controller.last_job,
                                                         lambda: controller.state() == "fault"))

    def start(self) -> None:
        self.store.prune()
        self.runner.start()

    def close(self) -> None:
        self.runner.close()
        self.checker.close()

    # ------------------------------------------------------------------ the library
    def add(self, name: str, text: str | ProgramFile) -> dict[str, Any]:
        """Check ``text`` (or the spooled file holding it) and keep it in the library."""
        from nurbsmotion.service.streamed_job import plan_request

        check_library_name(name)
        if isinstance(text, str):
            self.library.check_size(name, text)
        start_mm, options = self.controller.reading_start()
        request = plan_request(name, text, self.config, start_mm, options, self.store)
        report = self.checker.check(request, tuple(a.name for a in self.config.axes))
        self.store.note(report.from_store, name)
        if report.errors:
            log.info(kv("program_refused", name=name, errors=len(report.errors),
                        first=report.as_dict()["errors"][0]))
            raise as_error(report.errors)
        meta = self.library.add(name, text, text_digest(text), report.as_dict()) if isinstance(text, str) \
            else self.library.add_file(name, text, report.as_dict())
        log.info(kv("program_added", name=name, blocks=report.blocks, size_bytes=meta["size_bytes"],
                    checked_from_store=report.from_store))
        return {"ok": True, "program": meta}

    def listing(self) -> dict[str, Any]:
        return {"ok": True, "programs": self.library.listing(), "checked_store": self.store.counters()}

    def get(self, name: str) -> dict[str, Any]:
        return {"ok": True, "program": self.library.get(name)}

    def remove(self, name: str) -> dict[str, Any]:
        self.library.remove(name)
        log.info(kv("program_removed", name=name))
        return {"ok": True, "removed": name}

    def start_program(self, name: str, fields: dict[str, Any]) -> dict[str, Any]:
        """``start NAME``: the library's program submitted with ``fields`` (submit's options),
        as its file (service.program_file.snapshot: the daemon never reads its text)."""
        program = self.library.program_file(name, self.config.data_dir)
        try:
            return self.controller.submit(name, program, bool(fields.get("keep_override", False)),
                                          bool(fields.get("block_delete", True)),
                                          bool(fields.get("optional_stop", True)),
                                          start_line=start_line_field(fields.get("start_line")))
        finally:
            program.discard()

    # ------------------------------------------------------------------ the queue
    def queue_add(self, name: str, start_line: Any) -> dict[str, Any]:
        self.library.get(name)  # queued only what the library holds
        entry = self.queue.add(name, start_line_field(start_line))
        return {"ok": True, "entry": {"id": entry.id, "program": entry.program}, "queue": self.queue.snapshot()}

    def queue_answer(self, change: Callable[[], Any]) -> dict[str, Any]:
        change()
        return {"ok": True, "queue": self.queue.snapshot()}

    def _start_entry(self, entry: QueueEntry) -> str:
        """The queue runner's start of ``entry``: the job's id (InputError when refused)."""
        return str(self.start_program(entry.program, {"start_line": entry.start_line})["job"]["id"])

    def add_requested(self, request: Request) -> dict[str, Any]:
        """``programs.add`` with the program's text or the file sent along (service.program_file)."""
        with requested_program(request.fields, request.files, self.config.data_dir, self.library.max_bytes,
                               "web.max_upload_mb") as program:
            return self.add(request.fields["name"], program)

    def handlers(self, request: Request) -> dict[str, Callable[[], dict[str, Any]]]:
        """The daemon's request table entries (service.daemon.dispatch) for ``request``."""
        f = request.fields
        q = self.queue
        return {
            "programs.add": lambda: self.add_requested(request),
            "programs.list": self.listing,
            "programs.get": lambda: self.get(f["name"]),
            "programs.remove": lambda: self.remove(f["name"]),
            "start": lambda: self.start_program(f["name"], f),
            "queue.list": lambda: {"ok": True, "queue": q.snapshot()},
            "queue.add": lambda: self.queue_add(f["name"], f.get("start_line")),
            "queue.remove": lambda: self.queue_answer(lambda: q.remove(whole(f["id"], "id"))),
            "queue.move": lambda: self.queue_answer(lambda: q.move(whole(f["id"], "id"),
                                                                   whole(f["position"], "position"))),
            "queue.clear": lambda: self.queue_answer(q.clear),
            "queue.pause": lambda: self.queue_answer(lambda: q.pause("paused by the operator")),
            "queue.resume": lambda: self.queue_answer(q.resume),
        }


def whole(value: Any, name: str) -> int:
    """A whole-number field (JSON numbers may be 2.0)."""
    if float(value) != int(value):
        raise InputError(f"field {name!r}", f"must be a whole number, got {value!r}")
    return int(value)
