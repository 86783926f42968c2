"""The job queue's file and its runner's decisions, with the daemon replaced by hooks."""

from __future__ import annotations

import json
from types import SimpleNamespace
from pathlib import Path
from typing import Any

import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.service.job_queue import RESTARTED, JobQueue, QueueEntry, QueueHooks, QueueRunner


class Machine:
    """The hooks: idle or not, the jobs started, the last job's end, a fault."""

    def __init__(self) -> None:
        self.busy = False
        self.fault = False
        self.started: list[str] = []
        self.last: dict[str, Any] | None = None
        self.refuse: str | None = None

    def start(self, entry: QueueEntry) -> str:
        if self.refuse:
            raise InputError("submit", self.refuse)
        self.started.append(entry.program)
        self.busy = True
        return f"job{len(self.started)}"

    def end(self, outcome: str, reason: str = "") -> None:
        self.busy = False
        self.last = {"id": f"job{len(self.started)}", "name": self.started[-1], "outcome": outcome, "reason": reason}

    def hooks(self) -> QueueHooks:
        return QueueHooks(lambda: not self.busy, self.start, lambda: self.last, lambda: self.fault)


def test_entries_are_kept_in_order_across_a_restart_which_pauses_the_queue(tmp_path: Path):
    queue = JobQueue(tmp_path)
    first, second, third = (queue.add(name) for name in ("a.nc", "b.nc", "c.nc"))
    queue.move(third.id, 1)
    queue.remove(first.id)
    again = JobQueue(tmp_path)
    assert [e.program for e in again.entries] == ["c.nc", "b.nc"] and again.paused == RESTARTED
    assert again.add("d.nc").id == third.id + 1  # ids are never reused
    assert JobQueue(tmp_path / "empty").paused is None


def test_a_corrupt_queue_file_is_one_error_naming_it(tmp_path: Path):
    (tmp_path / "queue.json").write_text('{"entries": [{"id": 1, "program": "../x.nc"}]}')
    with pytest.raises(InputError) as err:
        JobQueue(tmp_path)
    assert err.value.where == str(tmp_path / "queue.json") and "move it away" in err.value.message


def test_bad_ids_positions_and_names_are_refused(tmp_path: Path):
    queue = JobQueue(tmp_path)
    with pytest.raises(InputError, match="no queue entry 5"):
        queue.remove(5)
    entry = queue.add("a.nc")
    with pytest.raises(InputError, match="must be 1 or more"):
        queue.move(entry.id, 0)
    with pytest.raises(InputError, match="program name"):
        queue.add("a/b.nc")
    assert json.loads((tmp_path / "queue.json").read_text())["entries"][0]["program"] == "a.nc"


def test_the_runner_starts_entries_one_after_another_and_pauses_on_a_job_that_does_not_complete(tmp_path: Path):
    queue, machine = JobQueue(tmp_path), Machine()
    runner = QueueRunner(queue, machine.hooks())
    for name in ("a.nc", "b.nc", "c.nc"):
        queue.add(name)
    runner.step()
    runner.step()  # busy: nothing more starts
    assert machine.started == ["a.nc"]
    machine.end("completed")
    runner.step()
    assert machine.started == ["a.nc", "b.nc"]
    machine.end("fault", "node 2: EMCY 0x2310")
    runner.step()
    assert queue.paused == "job job2 (b.nc) ended fault: node 2: EMCY 0x2310"
    runner.step()
    assert machine.started == ["a.nc", "b.nc"] and [e.program for e in queue.entries] == ["c.nc"]
    queue.resume()
    runner.step()
    assert machine.started[-1] == "c.nc" and not queue.entries


def test_a_refused_start_keeps_the_entry_first_and_a_fault_pauses_the_queue(tmp_path: Path):
    queue, machine = JobQueue(tmp_path), Machine()
    runner = QueueRunner(queue, machine.hooks())
    queue.add("a.nc")
    machine.refuse = "not homed: home the axes first"
    runner.step()
    assert queue.paused == "a.nc refused: submit: not homed: home the axes first"
    assert [e.program for e in queue.entries] == ["a.nc"]
    machine.refuse, machine.fault = None, True
    queue.resume()
    runner.step()
    assert queue.paused == "the drives are in fault: reset, then resume the queue" and machine.started == []


def test_the_library_commands_are_the_protocol_commands_programs_serves():
    from nurbsmotion.service.programs import LIBRARY_COMMANDS, Programs
    from nurbsmotion.service.protocol import COMMANDS, Request

    assert LIBRARY_COMMANDS <= set(COMMANDS)
    served = Programs.handlers(SimpleNamespace(queue=None, listing=None), Request("programs.list"))  # type: ignore[arg-type]
    assert set(served) == LIBRARY_COMMANDS
