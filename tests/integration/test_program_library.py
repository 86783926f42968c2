"""The program library and the job queue in a daemon with simulated drives (this process):
checked once when added, started by name without a second check, the checked-program store
invalidated by a changed file, configuration or entry, and both kept across a restart."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from nurbsmotion.service import streamed_job
from nurbsmotion.service.client import Client
from tests.helpers import wait_for
from tests.integration.daemon_helpers import daemon_in_process

SQUARE = "G21 G90\nG01 X4 Y3 F3000\nG01 X0 Y0\n"  # ends where it started: started again from there
LONG = "G21 G90\nG01 X40 F600\nG01 X0\n"  # ~8 s
BAD = "G21 G90\nG01 X4 Y3 F3000\nG01 X0 Q\n"


def call(daemon: Any, cmd: str, **fields: Any) -> dict[str, Any]:
    with Client(daemon.config.control.socket) as client:
        return client.request(cmd, **fields)


def job_end(daemon: Any, job_id: str, timeout_s: float = 30.0) -> dict[str, Any]:
    wait_for(lambda: daemon.controller.last_job() is not None and daemon.controller.last_job()["id"] == job_id,
               timeout_s, f"the end of job {job_id}")
    return daemon.controller.job_info(job_id)["job"]


def run_twice(daemon: Any, name: str, text: str) -> tuple[bool, bool]:
    """Submit ``text`` as ``name`` twice, each to its end: whether each came from the store."""
    from_store = []
    for _ in range(2):
        job = call(daemon, "submit", name=name, program=text)["job"]
        job_end(daemon, job["id"])
        from_store.append(job["summary"]["checked_from_store"])
    return from_store[0], from_store[1]


@pytest.fixture()
def data_dir(tmp_path: Path) -> Path:
    return tmp_path / "data"


def test_a_program_added_is_checked_once_and_started_by_name_without_a_second_check(data_dir):
    with daemon_in_process(data_dir, "", "lib") as daemon:
        added = call(daemon, "programs.add", name="square.nc", program=SQUARE)
        assert added["ok"], added
        check = added["program"]["check"]
        assert check["ok"] and check["blocks"] == 2 and check["errors"] == []
        assert check["lines"]["lines_total"] == 3
        assert check["extent"] == {"axes": ["X", "Y", "Z"], "min_mm": [0.0, 0.0, 0.0], "max_mm": [4.0, 3.0, 0.0]}
        assert (data_dir / "programs" / "square.nc").read_text() == SQUARE
        listing = call(daemon, "programs.list")
        assert [p["name"] for p in listing["programs"]] == ["square.nc"]
        assert call(daemon, "programs.get", name="square.nc")["program"]["text"] == SQUARE

        started = call(daemon, "start", name="square.nc")
        assert started["ok"], started
        assert started["job"]["summary"]["checked_from_store"] is True
        assert job_end(daemon, started["job"]["id"])["outcome"]["outcome"] == "completed"
        assert daemon.store.hits == 1 and daemon.store.misses == 1  # the add read it, the start did not

        # run FILE uses the same store: the first submit of a new name reads it, the second not
        assert run_twice(daemon, "other.nc", SQUARE) == (False, True)
        assert daemon.store.counters()["hits"] == 2 and daemon.store.counters()["misses"] == 2

        assert call(daemon, "programs.remove", name="square.nc")["ok"]
        assert call(daemon, "programs.list")["programs"] == []
        gone = call(daemon, "start", name="square.nc")
        assert not gone["ok"] and gone["error"] == "program 'square.nc': not in the library (nurbsmotion programs list)"


def test_a_refused_program_is_not_added_and_bad_names_are_refused(data_dir):
    with daemon_in_process(data_dir, "", "lib") as daemon:
        refused = call(daemon, "programs.add", name="bad.nc", program=BAD)
        assert not refused["ok"] and refused["error"].startswith("bad.nc:3:"), refused
        assert call(daemon, "programs.list")["programs"] == []
        beyond = call(daemon, "programs.add", name="far.nc", program="G21 G90\nG01 X150 F3000\n")
        assert not beyond["ok"] and "soft limit" in beyond["error"] and beyond["error"].startswith("far.nc:2")
        for name in ("../x.nc", "a/b.nc", ".hidden.nc", "", "x" * 129 + ".nc"):
            answer = call(daemon, "programs.add", name=name, program=SQUARE)
            assert not answer["ok"] and answer["error"].startswith("field 'name': program name"), (name, answer)
        kind = call(daemon, "programs.add", name="part.doc", program=SQUARE)
        assert not kind["ok"] and "unknown program type" in kind["error"]
        assert not (data_dir / "x.nc").exists() and call(daemon, "programs.list")["programs"] == []


def test_a_changed_file_configuration_or_entry_is_checked_again(data_dir):
    with daemon_in_process(data_dir, "", "lib") as daemon:
        assert call(daemon, "programs.add", name="square.nc", program=SQUARE)["ok"]
        (data_dir / "programs" / "square.nc").write_text(SQUARE.replace("X4 Y3", "X5 Y3"))  # edited by hand
        edited = call(daemon, "start", name="square.nc")
        assert edited["job"]["summary"]["checked_from_store"] is False
        job_end(daemon, edited["job"]["id"])
        for entry in (data_dir / "checked").glob("*.checked"):
            entry.write_bytes(entry.read_bytes()[:40] + b"garbage")  # corrupt: rechecked, never trusted
        corrupt = call(daemon, "start", name="square.nc")
        assert corrupt["job"]["summary"]["checked_from_store"] is False
        job_end(daemon, corrupt["job"]["id"])
        again = call(daemon, "start", name="square.nc")
        assert again["job"]["summary"]["checked_from_store"] is True
        job_end(daemon, again["job"]["id"])
    # the same data under another configuration: a section no check reads changed (web), then one
    # the checks read (machine.safe_z_mm)
    with daemon_in_process(data_dir, "web: {max_upload_mb: 32}\n", "lib") as daemon:
        same = call(daemon, "start", name="square.nc")
        assert same["job"]["summary"]["checked_from_store"] is True
        job_end(daemon, same["job"]["id"])
    with daemon_in_process(data_dir, "machine: {safe_z_mm: 5}\n", "lib") as daemon:
        other = call(daemon, "start", name="square.nc")
        assert other["ok"] and other["job"]["summary"]["checked_from_store"] is False
        job_end(daemon, other["job"]["id"])


def test_the_queue_runs_programs_in_order_stops_at_an_abort_and_survives_a_restart(data_dir):
    with daemon_in_process(data_dir, "", "lib") as daemon:
        for name, text in (("square.nc", SQUARE), ("long.nc", LONG)):
            assert call(daemon, "programs.add", name=name, program=text)["ok"]
        assert call(daemon, "queue.pause")["queue"]["paused"] == "paused by the operator"
        ids = [call(daemon, "queue.add", name=n)["entry"]["id"] for n in ("long.nc", "square.nc", "long.nc")]
        refused = call(daemon, "queue.add", name="missing.nc")
        assert not refused["ok"] and "not in the library" in refused["error"]
        moved = call(daemon, "queue.move", id=ids[1], position=1)["queue"]
        assert [e["program"] for e in moved["entries"]] == ["square.nc", "long.nc", "long.nc"]
        assert call(daemon, "status")["queue"] == {"entries": 3, "next": "square.nc", "paused": "paused by the operator"}
        assert call(daemon, "queue.resume")["ok"]
        wait_for(lambda: getattr(daemon.controller.running_job(), "name", None) == "long.nc", 20.0, "the second entry to run")
        assert daemon.controller.last_job()["name"] == "square.nc"
        assert daemon.controller.last_job()["outcome"] == "completed"
        during = call(daemon, "programs.add", name="while-running.nc", program=SQUARE)  # the checker process
        assert during["ok"] and getattr(daemon.controller.running_job(), "name", None) == "long.nc"
        assert call(daemon, "abort")["ok"]
        wait_for(lambda: daemon.programs.queue.paused is not None, 10.0, "the queue to pause")
        queue = call(daemon, "queue.list")["queue"]
        assert queue["paused"].endswith("(long.nc) ended aborted: aborted on request (quick stop)"), queue
        assert [e["id"] for e in queue["entries"]] == [ids[2]]
        assert call(daemon, "reset")["ok"]
    with daemon_in_process(data_dir, "", "lib") as daemon:  # restarted: the library and the queue are back
        assert [p["name"] for p in call(daemon, "programs.list")["programs"]] == ["long.nc", "square.nc",
                                                                                 "while-running.nc"]
        queue = call(daemon, "queue.list")["queue"]
        assert [e["id"] for e in queue["entries"]] == [ids[2]] and queue["paused"]
        assert call(daemon, "queue.remove", id=ids[2])["queue"]["entries"] == []
        bad = call(daemon, "queue.remove", id=99)
        assert not bad["ok"] and bad["error"] == "field 'id': no queue entry 99 (entries: none)"


def test_a_job_stopped_at_once_still_stores_its_checked_program(data_dir):
    with daemon_in_process(data_dir, "", "lib") as daemon:
        first = call(daemon, "submit", name="long.nc", program=LONG)
        assert call(daemon, "stop")["ok"]
        job_end(daemon, first["job"]["id"])
        assert call(daemon, "mdi", text="G53 G0 X0 Y0 Z0")["ok"]  # back where it started
        wait_for(lambda: daemon.controller.idle(), 20.0, "the MDI to end")
        second = call(daemon, "submit", name="long.nc", program=LONG)
        assert (first["job"]["summary"]["checked_from_store"], second["job"]["summary"]["checked_from_store"]) == \
            (False, True)
        assert call(daemon, "abort")["ok"]


def test_a_program_over_the_size_limit_is_refused_and_not_added(data_dir):
    with daemon_in_process(data_dir, "web: {max_upload_mb: 0.001}\n", "lib") as daemon:  # 1048 bytes
        big = call(daemon, "programs.add", name="big.nc", program=SQUARE * 40)
        assert not big["ok"] and big["error"] == (f"program 'big.nc': {len(SQUARE) * 40:,} bytes is larger than the "
                                                  "0.001 MB limit (web.max_upload_mb)")
        assert call(daemon, "programs.add", name="small.nc", program=SQUARE)["ok"]
        assert [p["name"] for p in call(daemon, "programs.list")["programs"]] == ["small.nc"]


def test_a_large_program_run_the_first_time_is_checked_in_the_checker_process_then_loaded(data_dir, monkeypatch):
    """Issue 25 item 7: reading a large program peaks at hundreds of MB: in the checker process,
    not the planner worker, which loads it from the store as any stored program."""
    monkeypatch.setattr(streamed_job, "LARGE_PROGRAM_CHARS", 10)  # SQUARE and BAD count as large
    with daemon_in_process(data_dir, "", "lib") as daemon:
        refused = call(daemon, "submit", name="bad.nc", program=BAD)
        assert not refused["ok"] and refused["error"].startswith("bad.nc:3:"), refused
        assert daemon.programs.checker._pool is not None  # the checker read it
        assert run_twice(daemon, "big.nc", SQUARE) == (False, True)
        assert daemon.store.counters()["misses"] == 1 and daemon.store.counters()["hits"] == 1


def sent_with_file(daemon: Any, path: Path, cmd: str, **fields: Any) -> dict[str, Any]:
    """``cmd`` with the open file passed along (protocol program_fd), as ``run`` and
    ``programs add`` send it."""
    with Client(daemon.config.control.socket) as client, open(path, "rb") as src:
        return client.request(cmd, files=[src.fileno()], program_fd=0, **fields)


def test_starts_and_files_sent_along_reach_the_worker_as_a_path_never_as_text(data_dir, tmp_path, monkeypatch):
    """Issue 25 item 7 (the daemon < 150 MB at 10^6 lines): ``start NAME`` and a program file
    passed with the request never put the text in the daemon: the planner worker's and the
    checker's requests carry the spool file's path; a text request still carries its text."""
    from nurbsmotion.service.program_check import ProgramChecker
    from nurbsmotion.service.program_library import ProgramLibrary

    requests: list[Any] = []
    check = ProgramChecker.check
    monkeypatch.setattr(ProgramChecker, "check", lambda self, request, axes: (requests.append(request),
                                                                              check(self, request, axes))[1])
    monkeypatch.setattr(ProgramLibrary, "get", lambda self, name: pytest.fail("the daemon read the library's text"))
    part = tmp_path / "part.nc"
    part.write_bytes(b"\xef\xbb\xbf" + SQUARE.encode())  # a byte-order mark, as CAM posts write
    with daemon_in_process(data_dir, "", "lib") as daemon:
        connect = daemon.planner_worker.connect
        monkeypatch.setattr(daemon.planner_worker, "connect", lambda request: (requests.append(request),
                                                                               connect(request))[1])
        added = sent_with_file(daemon, part, "programs.add", name="square.nc")
        assert added["ok"] and added["program"]["check"]["blocks"] == 2, added
        assert (data_dir / "programs" / "square.nc").read_text() == SQUARE  # moved from the spool, no mark
        for _ in range(2):
            started = call(daemon, "start", name="square.nc")
            assert started["ok"] and started["job"]["summary"]["checked_from_store"] is True, started
            assert Path(started["job"]["folder"], "program.nc").read_text() == SQUARE  # the record links it
            job_end(daemon, started["job"]["id"])
        (data_dir / "programs" / "square.nc").write_text(SQUARE.replace("X4 Y3", "X5 Y3"))  # edited by hand
        edited = call(daemon, "start", name="square.nc")
        assert edited["ok"] and edited["job"]["summary"]["checked_from_store"] is False  # the worker read the file
        job_end(daemon, edited["job"]["id"])
        assert call(daemon, "mdi", text="G53 G0 X0 Y0 Z0")["ok"]
        wait_for(lambda: daemon.controller.idle(), 20.0, "the MDI to end")
        ran = sent_with_file(daemon, part, "submit", name="part.nc")
        assert ran["ok"] and ran["job"]["summary"]["checked_from_store"] is False, ran
        job_end(daemon, ran["job"]["id"])
        text = call(daemon, "submit", name="text.nc", program=SQUARE)  # a remote client: the text itself
        assert text["ok"], text
        job_end(daemon, text["job"]["id"])
        assert list((data_dir / "spool").iterdir()) == []  # every spooled file discarded or moved
    by_path = [r for r in requests if r.name != "<mdi>"]
    assert [(r.name, r.text is None, r.text_file is not None) for r in by_path] == \
        [("square.nc", True, True)] * 4 + [("part.nc", True, True), ("text.nc", False, False)]
    assert by_path[-1].text == SQUARE
