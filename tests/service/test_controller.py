"""One job at a time: submit, watch, stop, fault and reset, override, records (fake link)."""

import time
from pathlib import Path

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.service.controller import Controller
from nurbsmotion.service.records import JobRecords
from tests.service.fakes import FakeLink, fake_planner

ROOT = Path(__file__).resolve().parents[2]


def _wait(condition, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


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
    _wait(_ended(controller))
    info = controller.job_info(job["id"])["job"]
    assert info["outcome"]["outcome"] == "completed"
    assert info["outcome"]["sent"] == info["outcome"]["planned"] == 200
    assert (Path(info["folder"]) / "program.nc").read_text() == "X5"
    assert controller.status()["last_job"]["outcome"] == "completed"
    assert link.held[0] == 5000  # counts_per_mm 1000


def test_a_bad_program_is_rejected_and_nothing_moves(parts, tmp_path):
    controller, link = parts
    with pytest.raises(InputError, match="bad.nc:1"):
        controller.submit("bad.nc", "G99")
    assert link.job is None and link.held == [0, 0, 0]
    assert not (tmp_path / "jobs").exists()


def test_one_job_at_a_time(parts):
    controller, link = parts
    link.cycle_s = 0.01
    controller.submit("a.nc", "X5")
    with pytest.raises(InputError, match="busy"):
        controller.submit("b.nc", "X1")
    controller.stop()
    _wait(_ended(controller))
    assert controller.status()["last_job"]["outcome"] == "stopped"


def test_a_fault_is_recorded_and_reset_allows_a_new_job(parts):
    controller, link = parts
    link.fault_at = 50
    job = controller.submit("a.nc", "X5")["job"]
    _wait(_ended(controller))
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
    _wait(_ended(controller))
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
    _wait(_ended(controller))
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
