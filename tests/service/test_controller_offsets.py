"""The controller keeps the program's coordinate state between jobs (offsets.json), passes it
and the switches to the reader, and changes offsets only between jobs."""

import time
from pathlib import Path

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError, Refused
from nurbsmotion.service.controller import Controller
from nurbsmotion.service.machine_state import load_state
from nurbsmotion.service.planner import plan_job
from nurbsmotion.service.records import JobRecords
from tests.service.fakes import FakeLink, with_data_dir
from tests.helpers import wait_for

ROOT = Path(__file__).resolve().parents[2]


def _idle(controller) -> bool:
    status = controller.status()
    return status["state"] == "idle" and status["job"] is None


@pytest.fixture
def controller(tmp_path):
    config = with_data_dir(load_config(ROOT / "config" / "demo.yaml"), str(tmp_path / "data"), str(tmp_path / "s"))
    link = FakeLink(config, cycle_s=0.0005)
    c = Controller(config, link, lambda n, t, s, o: plan_job(n, t, config, s, o), JobRecords(tmp_path / "jobs"))
    try:
        yield c
    finally:
        c.shutdown(2.0)


def test_a_completed_programs_offsets_are_persisted_and_used_by_the_next(controller):
    job = controller.submit("setup.nc", "G21 G90\nG10 L2 P2 X5 Y1\nG55\nG1 X1 F3000\n")["job"]
    assert job["summary"]["end_mm"][0] == pytest.approx(6.0)
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)
    saved = load_state(controller.config.data_dir)
    assert saved.coordinates.active_name == "G55" and saved.coordinates.work_offsets_mm[1] == (5.0, 1.0, 0.0)
    assert controller.status()["coordinates"]["active"] == "G55"
    job = controller.submit("next.nc", "G21 G90\nG1 X2 Y0 F3000\n")["job"]  # starts in G55 with its offset
    assert job["summary"]["end_mm"][:2] == pytest.approx([7.0, 1.0])
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)


def test_a_stopped_job_keeps_the_state_it_started_from(controller):
    controller.submit("long.nc", "G21 G90\nG1 X20 F600\nG10 L2 P1 X9\n")
    time.sleep(0.05)
    controller.stop()
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)
    assert controller.status()["last_job"]["outcome"] == "stopped"
    assert load_state(controller.config.data_dir).coordinates.work_offsets_mm[0] == (0.0, 0.0, 0.0)


def test_offsets_are_set_cleared_and_selected_between_jobs_only(controller):
    shown = controller.offsets({"system": "G56", "x": 10.0, "y": -5.0, "z": 0.0})["offsets"]
    assert shown["work_offsets_mm"]["G56"] == [10.0, -5.0, 0.0] and shown["active"] == "G54"
    assert controller.offsets({"select": "G56"})["offsets"]["active"] == "G56"
    assert load_state(controller.config.data_dir).coordinates.active_name == "G56"
    job = controller.submit("a.nc", "G21 G90\nG1 X1 Y1 F3000\n")["job"]
    assert job["summary"]["end_mm"][:2] == pytest.approx([11.0, -4.0])
    with pytest.raises(Refused, match="offsets: a job is running; offsets change only between jobs"):
        controller.offsets({"clear": "G56"})
    assert controller.offsets({})["offsets"]["work_offsets_mm"]["G56"] == [10.0, -5.0, 0.0]  # showing is fine
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)
    assert controller.offsets({"clear": "G56"})["offsets"]["work_offsets_mm"]["G56"] == [0.0, 0.0, 0.0]
    with pytest.raises(InputError, match="field 'system': required with x, y or z"):
        controller.offsets({"x": 1.0})


def test_the_switches_of_the_submission_reach_the_reader(controller):
    program = "G21 G90\n/G1 X5 F3000\nG1 X1 F3000\nM1\nG1 X2\n"
    job = controller.submit("part.nc", program)["job"]
    assert [p["reason"] for p in job["summary"]["pauses"]] == ["M1 at part.nc:4"] and job["summary"]["blocks"] == 2
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)
    job = controller.submit("part.nc", program, block_delete=False, optional_stop=False)["job"]
    assert job["summary"]["blocks"] == 3 and job["summary"]["pauses"] == []  # the '/' line ran too, M1 is nothing
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)


def test_the_tool_table_of_the_machine_applies(controller, tmp_path):
    import dataclasses

    from nurbsmotion.program import parse_tool_table
    controller.config = dataclasses.replace(controller.config, tool_table=parse_tool_table(
        "tools:\n  - {number: 3, length_mm: 2.5, diameter_mm: 6}\n", "t.yaml"))
    job = controller.submit("t.nc", "G21 G90\nG43 H3\nG1 Z1 F3000\n")["job"]
    assert job["summary"]["end_mm"][2] == pytest.approx(3.5)
    wait_for(lambda: _idle(controller), 10.0, "the controller idle", 0.005)
