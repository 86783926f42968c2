"""One job at a time: submit, watch, stop, fault and reset, override, records (fake link)."""

import csv
import dataclasses
import functools
import json
import logging
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.service.controller import FAST_FIELDS, Controller
from nurbsmotion.service.planner import plan_job
from nurbsmotion.service.records import JobRecords
from tests.service.fakes import FakeLink, fake_planner
from tests.helpers import wait_for as _wait_for

wait_for = functools.partial(_wait_for, timeout_s=5.0, poll_s=0.005)  # this module's waits

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def parts(tmp_path):
    config = load_config(ROOT / "config" / "demo.yaml")
    link = FakeLink(config)
    controller = Controller(config, link, fake_planner(config), JobRecords(tmp_path))
    try:
        yield controller, link
    finally:
        controller.shutdown(2.0)


def _ended(controller):
    return lambda: controller.status()["job"] is None


def test_a_job_runs_to_completion_and_leaves_its_record(parts):
    controller, link = parts
    job = controller.submit("line.nc", "X5")["job"]
    assert controller.status()["state"] in ("running", "idle")
    wait_for(_ended(controller))
    info = controller.job_info(job["id"])["job"]
    assert info["outcome"]["outcome"] == "completed"
    assert info["outcome"]["sent"] == info["outcome"]["planned"] == 200
    assert (Path(info["folder"]) / "program.nc").read_text() == "X5"
    assert controller.status()["last_job"]["outcome"] == "completed"
    assert link.held[0] == 5000  # counts_per_mm 1000


def test_a_bad_program_is_rejected_nothing_moves_and_the_rejection_leaves_a_record(parts, tmp_path, caplog):
    controller, link = parts
    with caplog.at_level(logging.INFO, logger="nurbsmotion"):
        with pytest.raises(InputError, match="bad.nc:1"):
            controller.submit("bad.nc", "G99")
    assert link.job is None and link.held == [0, 0, 0] and link.feedback is None
    [record] = controller.jobs()["jobs"]
    assert record["outcome"] == "rejected" and record["name"] == "bad.nc"
    info = controller.job_info(record["id"])["job"]
    assert info["outcome"]["errors"] == ["bad.nc:1: unknown word 'G99'"]
    assert info["files"] == ["outcome.json", "program.nc"]
    [line] = [r.getMessage() for r in caplog.records if "submit_rejected" in r.getMessage()]
    assert f"record={record['id']}" in line and 'first="bad.nc:1: unknown word' in line


def test_one_job_at_a_time(parts):
    controller, link = parts
    link.cycle_s = 0.01
    controller.submit("a.nc", "X5")
    with pytest.raises(InputError, match="busy"):
        controller.submit("b.nc", "X1")
    controller.stop()
    wait_for(_ended(controller))
    assert controller.status()["last_job"]["outcome"] == "stopped"


def test_a_fault_is_recorded_and_reset_allows_a_new_job(parts):
    controller, link = parts
    link.fault_at = 50
    job = controller.submit("a.nc", "X5")["job"]
    wait_for(_ended(controller))
    status = controller.status()
    assert status["state"] == "fault" and status["faults"][0]["node"] == 2
    outcome = controller.job_info(job["id"])["job"]["outcome"]
    assert outcome["outcome"] == "fault" and outcome["fault"]["code"] == 0x2310
    with pytest.raises(InputError, match="reset"):
        controller.submit("b.nc", "X1")
    link.fault_at = None
    controller.reset()
    assert controller.status()["state"] == "idle" and controller.status()["faults"] == []
    controller.submit("b.nc", f"X{link.held[0] / 1000 + 1}")
    wait_for(_ended(controller))
    assert controller.status()["last_job"]["outcome"] == "completed"


def test_override_is_checked_and_clamped_to_the_plan_limit(parts):
    controller, link = parts
    with pytest.raises(InputError, match="'percent'"):
        controller.override(151)
    link.cycle_s = 0.01
    controller.submit("a.nc", "X5")  # the fake plan allows 120 %
    response = controller.override(150)
    assert response["effective_percent"] == pytest.approx(120.0) and link.rate == pytest.approx(1.2)
    controller.override(50)
    assert link.rate == pytest.approx(0.5)
    assert controller.status()["override"]["effective_percent"] == pytest.approx(50.0)
    controller.abort()
    wait_for(_ended(controller))
    assert controller.status()["last_job"]["outcome"] == "aborted"


def test_shutdown_stops_the_running_job_and_records_it(parts):
    controller, link = parts
    link.cycle_s = 0.01
    job = controller.submit("a.nc", "X5")["job"]
    controller.shutdown(2.0)
    assert link.shut
    outcome = controller.job_info(job["id"])["job"]["outcome"]
    assert outcome["outcome"] == "stopped" and "daemon" in outcome["reason"]


@pytest.mark.parametrize("name", ["", "a\nb.nc", "x" * 256])
def test_program_names_must_be_printable_file_names(parts, name):
    controller, link = parts
    with pytest.raises(InputError, match="'name'"):
        controller.submit(name, "X1")
    assert link.job is None


def test_a_job_whose_record_cannot_be_written_does_not_start(tmp_path):
    config = load_config(ROOT / "config" / "demo.yaml")
    link = FakeLink(config)
    (tmp_path / "jobs").write_text("not a folder")
    controller = Controller(config, link, fake_planner(config), JobRecords(tmp_path))
    with pytest.raises(InputError, match="data_dir"):
        controller.submit("a.nc", "X5")
    assert link.job is None and controller.status()["state"] == "idle"


def test_a_record_holds_the_config_times_final_position_feedback_and_override_history(parts):
    controller, link = parts
    link.cycle_s = 0.005
    job = controller.submit("line.nc", "X5")["job"]
    wait_for(lambda: (controller.status()["job"] or {}).get("cycle", 0) > 20)
    controller.override(50)
    wait_for(_ended(controller))
    info = controller.job_info(job["id"])["job"]
    folder, outcome = Path(info["folder"]), info["outcome"]
    config = json.loads((folder / "config.json").read_text())
    assert config["cycle_period_s"] == controller.config.cycle_period_s and config["axes"][0]["name"] == "X"
    assert outcome["started_at"] < outcome["ended_at"] and outcome["start_cycle"] == 1001
    assert outcome["final_position"]["X"] == {"commanded_mm": 5.0, "actual_mm": 5.0}
    history = outcome["overrides"]
    assert [(h["by"], h["requested_percent"]) for h in history] == [("job_start", 100.0), ("request", 50.0)]
    assert 20 <= history[1]["setpoint"] < 200 and history[1]["at_s"] > 0
    with open(folder / "feedback.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == outcome["feedback_rows"] == 3 * 200
    assert [int(r["job_cycle"]) for r in rows[::3]] == list(range(200))  # job-relative, not the link's
    assert rows[-3]["axis"] == "X" and int(rows[-3]["position_counts"]) == 5000
    assert float(rows[-3]["position_mm"]) == 5.0 and int(rows[-3]["statusword"]) == 0x1237


def test_the_override_resets_to_100_percent_for_each_job_unless_kept(parts):
    controller, link = parts
    controller.override(40)
    controller.submit("a.nc", "X1")
    assert controller.status()["override"]["requested_percent"] == 100.0 and link.rate == 1.0
    wait_for(_ended(controller))
    controller.override(40)
    controller.submit("b.nc", "X2", keep_override=True)
    status = controller.status()
    assert status["override"]["requested_percent"] == 40.0 and link.rate == pytest.approx(0.4)
    assert status["job"] is None or status["job"]["override_percent"] == 40.0
    wait_for(_ended(controller))


def test_a_following_error_fault_has_no_code_its_error_in_counts_and_mm_and_a_job_cycle(parts):
    controller, link = parts
    link.fault_at, link.fault_kind, link.fault_code = 30, "following_error", -2345
    job = controller.submit("a.nc", "X5")["job"]
    wait_for(_ended(controller))
    fault = controller.job_info(job["id"])["job"]["outcome"]["fault"]
    assert fault["code"] is None and fault["kind"] == "following_error"
    assert fault["measured"] == {"following_error_counts": -2345, "following_error_mm": -2.345}
    assert fault["cycle"] == 30 and fault["master_cycle"] == 1031 and "at job cycle 30" in fault["message"]
    assert controller.status()["faults"] == [fault]  # the status tells it the same way as the record
    controller.reset()


def test_an_emcy_fault_carries_its_code(parts):
    controller, link = parts
    link.fault_at = 10
    job = controller.submit("a.nc", "X5")["job"]
    wait_for(_ended(controller))
    fault = controller.job_info(job["id"])["job"]["outcome"]["fault"]
    assert (fault["code"], fault["code_hex"], fault["measured"], fault["cycle"]) == (0x2310, "0x2310", None, 10)
    controller.reset()


def test_jobs_lists_the_newest_first_and_marks_the_running_one(parts):
    controller, link = parts
    first = controller.submit("a.nc", "X1")["job"]["id"]
    wait_for(_ended(controller))
    link.cycle_s = 0.01
    second = controller.submit("b.nc", "X2")["job"]["id"]
    listing = controller.jobs()
    assert [j["id"] for j in listing["jobs"]] == [second, first] and listing["total"] == 2
    assert listing["jobs"][0]["running"] and listing["jobs"][0]["outcome"] is None
    assert listing["jobs"][1]["outcome"] == "completed" and listing["jobs"][1]["name"] == "a.nc"
    assert [j["id"] for j in controller.jobs(1)["jobs"]] == [second]
    with pytest.raises(InputError, match="'limit'"):
        controller.jobs(0)
    controller.stop()
    wait_for(_ended(controller))


def test_with_the_real_planner_the_record_names_the_line_reached(tmp_path):
    config = load_config(ROOT / "config" / "demo.yaml")
    link = FakeLink(config, cycle_s=0.0005)
    controller = Controller(config, link, lambda n, t, s, o: plan_job(n, t, config, s, o), JobRecords(tmp_path))
    try:
        job = controller.submit("part.nc", "G21 G90\nG01 X2 F3000\n\nG01 X2 Y3\nM30\nG01 X9\n")["job"]
        # the submit's summary says how much of the file was read (issue 26.5)
        assert job["summary"]["reading"] == {"lines_total": 6, "last_line": 5, "ended_by": "M30", "lines_not_read": 1}
        wait_for(_ended(controller))
        outcome = controller.job_info(job["id"])["job"]["outcome"]
        assert outcome["line_reached"]["where"] == "part.nc:4" and outcome["line_reached"]["text"] == "G01 X2 Y3"
        assert controller.status()["last_job"]["line_reached"] == "part.nc:4"
    finally:
        controller.shutdown(2.0)


def test_feedback_log_false_records_no_feedback(tmp_path):
    config = load_config(ROOT / "config" / "demo.yaml")
    config = dataclasses.replace(config, monitoring=dataclasses.replace(config.monitoring, feedback_log=False))
    link = FakeLink(config)
    controller = Controller(config, link, fake_planner(config), JobRecords(tmp_path))
    try:
        job = controller.submit("a.nc", "X1")["job"]
        wait_for(_ended(controller))
        info = controller.job_info(job["id"])["job"]
        assert "feedback.csv" not in info["files"] and info["outcome"]["feedback_rows"] is None
        assert link.feedback is None
    finally:
        controller.shutdown(2.0)


def test_after_an_abort_the_progress_shows_where_the_job_stopped(parts, monkeypatch):
    """Between the end of a job and its record (settling, files) the master no longer reports
    it: the progress line read 'cycle 0/1791' after an abort (issue 26.6)."""
    import threading

    controller, link = parts
    recorded = threading.Event()
    settle = controller.outcomes.settled_status
    monkeypatch.setattr(controller.outcomes, "settled_status", lambda: (recorded.wait(5.0), settle())[1])
    job = controller.submit("line.nc", "X5")["job"]
    wait_for(lambda: (controller.status()["job"] or {}).get("cycle", 0) >= 50)
    controller.abort()
    wait_for(lambda: link.job is None)  # the master let go of it; its record is not written yet
    status = controller.status()
    recorded.set()
    assert status["job"]["id"] == job["id"] and status["state"] == "fault"
    assert status["job"]["cycle"] >= 50 and status["job"]["cycle"] == link_sent(controller, job["id"])


def link_sent(controller, job_id):
    wait_for(_ended(controller))
    return controller.job_info(job_id)["job"]["outcome"]["sent"]


def test_a_start_that_fails_unexpectedly_leaves_no_record(parts, monkeypatch):
    """An internal error as streaming starts (a race in the master, 1 of 50 demo runs) left a
    folder without outcome, marked 'interrupted' by the next daemon: a stray job."""
    controller, link = parts

    def broken(*args, **kwargs):
        raise RuntimeError("deque mutated during iteration")

    monkeypatch.setattr(link, "stream", broken)
    with pytest.raises(RuntimeError):
        controller.submit("line.nc", "X5")
    assert controller.records.all() == [] and controller.status()["job"] is None


def test_the_fast_fields_are_those_of_the_whole_status_with_positions_as_the_axis_map_converts(parts):
    controller, link = parts
    link.held = [1234, -567, 89]
    link.axis_map.offset_counts[0] = 100  # as homing sets it
    link.axis_map.sign[1] = -1.0  # an inverted axis
    status = controller.status()
    steps = controller.status_steps(fast_only=True)
    pauses = 0
    while True:  # the publisher runs it step by step (fieldbus.cycle_slack)
        try:
            next(steps)
            pauses += 1
        except StopIteration as done:
            fast = done.value
            break
    assert tuple(fast) == FAST_FIELDS and fast == {k: status[k] for k in FAST_FIELDS}
    assert set(status) - set(FAST_FIELDS) >= {"override", "coordinates", "homing", "last_job"}
    assert pauses == 3
    expected_mm = link.axis_map.to_mm(np.array([link.held]))[0]
    for axis, mm in zip(status["axes"], expected_mm):
        assert axis["commanded_mm"] == axis["actual_mm"] == round(float(mm), 6)
    assert [axis["actual_mm"] for axis in status["axes"]] == [1.134, 0.567, 0.089]
